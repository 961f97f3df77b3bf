"""C sources compiled into shared libraries through the compile cache and loaded with ctypes
(the SIMD sums over candidates, the recursions over a record): one build per source, flags and
compiler, kept in :func:`~casest._casadi.numerics.cache_dir` beside CasADi's JIT libraries."""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
import threading

from .ccache import entry_digest
from .ccache import valid as valid_entry
from .numerics import LOADED_LIBRARIES, c_compiler, cache_dir, cache_usable, compiler_id, record_compile

__all__ = ["load_library"]

_LOCK = threading.Lock()
_WARNED: set = set()  # cache folders already warned about in this process


def _warn_once(folder: str, err: OSError) -> None:
    """One warning per folder that could not take a library (a full disk, a read-only mount)."""
    import warnings

    if folder not in _WARNED:
        _WARNED.add(folder)
        warnings.warn(f"the compile cache folder {folder!r} cannot take a library ({err.strerror or err}): compiling "
                      "without the cache (each process compiles again); free space there or set CASEST_CACHE_DIR",
                      RuntimeWarning, stacklevel=4)


def _build(source: str, folder: str, stem: str, flags: tuple, link_variants: tuple) -> str | None:
    """Compile ``source`` into ``folder/stem.so`` (written under a temporary name, then renamed),
    trying each entry of ``link_variants`` (extra arguments after the source) in turn."""
    cc = c_compiler()
    with tempfile.TemporaryDirectory(prefix="casest_c_") as work:
        c_path, so_tmp = os.path.join(work, stem + ".c"), os.path.join(work, stem + ".so")
        with open(c_path, "w", encoding="utf-8") as fh:
            fh.write(source)
        for extra in link_variants:
            # libraries after the source: -Wl,-z,defs refuses a library with unresolved names
            command = [cc, *flags, c_path, "-o", so_tmp, *extra]
            try:
                done = subprocess.run(command, capture_output=True, text=True, timeout=600)
            except (OSError, subprocess.SubprocessError):
                return None
            if done.returncode == 0:
                break
        else:
            return None
        os.makedirs(folder, exist_ok=True)
        target = os.path.join(folder, stem + ".so")
        handle, staged = tempfile.mkstemp(prefix=stem, suffix=".so.part", dir=folder)
        os.close(handle)
        shutil.copyfile(so_tmp, staged)
        handle, digest = tempfile.mkstemp(prefix=stem, suffix=".sha256.part", dir=folder)
        with os.fdopen(handle, "w", encoding="ascii") as fh:  # the entry's digest: loaded only when it matches
            with open(staged, "rb") as built:
                fh.write(entry_digest(target, built.read()))
        os.replace(staged, target)
        os.replace(digest, os.path.join(folder, stem + ".sha256"))
        return target


def load_library(source: str, flags: tuple, link_variants: tuple = (("-lm",),), prefix: str = "lib_",
                 cached_only: bool = False) -> ctypes.CDLL | None:
    """The loaded library of a C source: from this process, the compile cache, or compiled now.

    Parameters
    ----------
    source : str
        The C text.
    flags : tuple of str
        Compiler flags (with ``-shared -fPIC``); part of the cache key with the compiler's id.
    link_variants : tuple of tuple of str
        Arguments after the source, tried in turn until one links (for instance libmvec, then
        libm alone).
    prefix : str
        The cached file's name prefix.
    cached_only : bool
        Load the library only if this process or the compile cache has it; never compile.

    Returns
    -------
    ctypes.CDLL or None
        None when compiling fails with every variant, or with ``cached_only`` when it is not
        compiled yet (the caller keeps its own path).
    """
    cc = c_compiler()
    key = hashlib.sha256("\0".join([source, " ".join(flags), compiler_id(cc)]).encode()).hexdigest()
    with _LOCK:
        if key in LOADED_LIBRARIES:
            return LOADED_LIBRARIES[key]
        folder = cache_dir() if cache_usable() else tempfile.mkdtemp(prefix="casest_c_")
        stem = prefix + key[:32]
        path = os.path.join(folder, stem + ".so")
        library, damaged = None, False
        if os.path.exists(path):
            # a truncated or altered library can crash the process when loaded (a bus error, not an
            # exception): only an entry whose digest matches is loaded, any other is compiled again
            damaged = not valid_entry(path)
            if not damaged:
                try:
                    library = ctypes.CDLL(path)
                    record_compile("hit")
                except OSError:
                    damaged = True
        if library is None:
            if cached_only:
                return None
            try:
                built = _build(source, folder, stem, flags, link_variants)
            except OSError as err:  # a full or unwritable cache: built outside it, as without a cache
                _warn_once(folder, err)
                built = _build(source, tempfile.mkdtemp(prefix="casest_c_"), stem, flags, link_variants)
            if built is None:
                return None
            library = ctypes.CDLL(built)
            record_compile("rebuilt" if damaged else "compiled")
        LOADED_LIBRARIES[key] = library
        return library
