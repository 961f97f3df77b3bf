"""Low-level numerics shared by every stage: evaluation of CasADi Functions on NumPy arrays,
C compilation, threads, and the lossless JSON form of arrays.

This module imports nothing else from casest, so that every other module may use it.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import os
import shutil
import threading
import warnings

import casadi as ca

from . import ccache
from .cache_folder import cache_dir, cache_info, cache_usable, clear_cache  # noqa: F401 (re-exported)
from .memory import register_memory_cache


__all__ = [
    "take_background_compiles",
    "library_in_cache",
    "library_state",
    "library_key",
    "MIN_SAMPLES_PER_THREAD",
    "available_cores",
    "COMPILE_STATS",
    "compile_stats",
    "cache_dir",
    "cache_info",
    "clear_cache",
    "compile_function",
    "compile_library",
    "compiling_ahead",
    "compiler_available",
    "default_threads",
]

#: What :func:`compile_function` did in this process (for benchmarks and tests).
COMPILE_STATS = {"jit_functions": 0, "memory_hits": 0}
_LOADED: dict = {}  # key -> loaded Function: one load per structure per process
_PREFETCHING: dict = {}  # key -> the background process compiling that source into the cache
_LOCK = threading.Lock()


_JIT_FOLDER: list = []


def _jit_folder() -> str:
    """This process's private folder for CasADi's JIT source and library files."""
    if not _JIT_FOLDER:
        import atexit
        import tempfile

        _remove_orphaned_jit_folders(tempfile.gettempdir())
        _JIT_FOLDER.append(tempfile.mkdtemp(prefix=f"casest_jit_{os.getpid()}_"))
        # the folder goes at exit (CasADi's own clean-up is off: the files would be gone
        # before it runs); the loaded libraries stay mapped after their files are removed
        atexit.register(_remove_jit_folder, _JIT_FOLDER[0], os.getpid())
    return _JIT_FOLDER[0]


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` exists (ours or another user's)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def _remove_orphaned_jit_folders(temp: str, min_age_s: float = 3600.0) -> None:
    """Remove JIT folders left by killed processes (kill -9 skips the exit clean-up): those
    whose owner is gone and that have not changed for ``min_age_s`` (an hour keeps clear of
    another PID namespace's live process sharing this temporary folder)."""
    import time

    with contextlib.suppress(OSError):
        for entry in os.scandir(temp):
            parts = entry.name.split("_")
            if len(parts) < 4 or parts[:2] != ["casest", "jit"] or not parts[2].isdigit():
                continue
            with contextlib.suppress(OSError):
                stale = time.time() - entry.stat().st_mtime > min_age_s
                if stale and entry.is_dir() and not process_alive(int(parts[2])):
                    shutil.rmtree(entry.path, ignore_errors=True)


def _remove_jit_folder(folder: str, owner: int) -> None:
    if os.getpid() == owner:  # not from a forked child that inherited the handler
        shutil.rmtree(folder, ignore_errors=True)


def compile_stats() -> dict:
    """C compiles requested by this process, by outcome: ``compiled`` (a new library),
    ``hit`` (taken from the cache), ``rebuilt`` (a corrupt entry compiled again)."""
    out = {"compiled": 0, "hit": 0, "rebuilt": 0}
    if _JIT_FOLDER and os.path.exists(os.path.join(_JIT_FOLDER[0], "compiles.log")):
        with open(os.path.join(_JIT_FOLDER[0], "compiles.log"), encoding="ascii") as fh:
            for line in fh:
                out[line.strip()] = out.get(line.strip(), 0) + 1
    return out


def _forget_loaded() -> None:
    with _LOCK:
        _LOADED.clear()
        LOADED_LIBRARIES.clear()


#: Libraries compiled outside CasADi's JIT (the SIMD sums), by source key: forgotten with the rest.
LOADED_LIBRARIES: dict = {}
register_memory_cache(_forget_loaded)


def record_compile(event: str) -> None:
    """Count a compile outside CasADi's JIT in :func:`compile_stats` (``compiled``, ``hit``, ``rebuilt``)."""
    with open(os.path.join(_jit_folder(), "compiles.log"), "a", encoding="ascii") as fh:
        fh.write(event + "\n")


#: Smallest block of samples worth a thread of its own.
MIN_SAMPLES_PER_THREAD = 2000


def compiler_available() -> bool:
    """True when a C compiler for CasADi's ``shell`` JIT is on the PATH (looked up once per
    value of ``$CC`` and ``$PATH``: a lookup stats every folder of the PATH)."""
    key = (os.environ.get("CC"), os.environ.get("PATH"))
    if key not in _COMPILER_FOUND:
        _COMPILER_FOUND[key] = bool(shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc"))
    return _COMPILER_FOUND[key]


_COMPILER_FOUND: dict = {}


def c_compiler() -> str:
    """The C compiler command: ``$CC``, else gcc, else cc (looked up once per value of ``$CC``
    and ``$PATH``, as :func:`compiler_available`)."""
    key = (os.environ.get("CC"), os.environ.get("PATH"))
    if key not in _COMPILER_COMMAND:
        _COMPILER_COMMAND[key] = os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc") or "cc"
    return _COMPILER_COMMAND[key]


_COMPILER_COMMAND: dict = {}


def compiler_id(cc: str) -> str:
    """The first line of ``cc --version`` and a digest of the CPU's instruction sets (kept in
    ``$CASEST_CC_ID``), part of every compile-cache key: libraries built with ``-march=native``
    are not taken from a cache shared with a machine of another CPU."""
    if not os.environ.get("CASEST_CC_ID"):
        import subprocess

        try:
            version = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=60).stdout
        except (OSError, subprocess.SubprocessError):
            return cc
        os.environ["CASEST_CC_ID"] = (version.splitlines() or [cc])[0] + " cpu " + _cpu_signature()
    return os.environ["CASEST_CC_ID"]


def _cpu_signature() -> str:
    """A short digest of the CPU's flags line (Linux), else of the platform's machine name."""
    import platform

    text = platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            text = next((line for line in fh if line.startswith("flags")), text)
    except OSError:
        pass
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def available_cores() -> int:
    """Cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def default_threads(n_samples: int) -> int:
    """Threads for sums over ``n_samples``: one per core, one block >= 2000 samples each."""
    return int(max(1, min(available_cores(), n_samples // MIN_SAMPLES_PER_THREAD)))


def _source_key(fun: ca.Function, flags) -> str | None:
    """A hash of the C source CasADi generates for ``fun`` and the flags (None if it cannot generate it)."""
    try:
        gen = ca.CodeGenerator(f"{fun.name()}.c")
        gen.add(fun)
        return hashlib.sha256((gen.dump() + "\0" + " ".join(flags)).encode()).hexdigest()
    except RuntimeError:
        return None


def _jit_function(fun: ca.Function, options: dict | None = None) -> ca.Function:
    """The MX Function that :func:`compile_function` hands CasADi's JIT for ``fun`` (``options``:
    the JIT's); without options, the same function uncompiled, whose generated C is the JIT's."""
    inputs = [ca.MX.sym(fun.name_in(k), fun.sparsity_in(k)) for k in range(fun.n_in())]
    outputs = fun(*inputs)
    outputs = list(outputs) if isinstance(outputs, (list, tuple)) else [outputs]
    return ca.Function(fun.name() + "_c", inputs, outputs, fun.name_in(), fun.name_out(), options or {})


def _jit_source(fun: ca.Function) -> str:
    """Write the C file CasADi's shell JIT writes for ``fun`` (the same text: code generated with
    the prefix ``jit``) into this process's JIT folder; its path."""
    folder = _jit_folder()
    # a name CasADi accepts (mkstemp's suffixes may hold "__", which it refuses), unique in the folder
    stem = f"{fun.name()}_ahead{next(_SOURCE_NUMBERS)}"
    gen = ca.CodeGenerator(stem + ".c", {"prefix": "jit"})
    gen.add(_jit_function(fun))
    gen.generate(folder + os.sep)
    return os.path.join(folder, stem + ".c")


def _library_key(source: str, arguments: list, cc: str) -> str:
    """The compile cache's key of ``source`` compiled with ``arguments`` (as
    :mod:`casest._casadi.ccache` computes it: the source's text, the flags, the compiler's id)."""
    h = hashlib.sha256()
    with open(source, "rb") as fh:
        h.update(fh.read())
    h.update("\0".join(arguments + [compiler_id(cc)]).encode())
    return h.hexdigest()[:32]


def prefetch_compile(fun: ca.Function, flags=("-O2",), library: bool = False) -> bool:
    """Compile ``fun`` into the compile cache in the background; a later :func:`compile_function`
    (with ``library``: :func:`compile_library`) of the same source waits
    for it and loads the cached library.

    The C file is the one CasADi's JIT will write, compiled by the cache's own compiler wrapper
    (:mod:`casest._casadi.ccache`) in a process of its own, so the compile runs on another core
    while this process goes on (a thread cannot: CasADi's reference counts are not atomic).

    Parameters
    ----------
    fun : casadi.Function
    flags : tuple of str
        The compiler flags :func:`compile_function` will be given.
    library : bool
        Build the linked library ``compile_library`` loads, not the object CasADi's JIT links.

    Returns
    -------
    bool
        Whether a compile was started: not without a usable compile cache or a compiler, nor
        when this source is loaded, being compiled, or already in the cache.
    """
    import subprocess
    import sys

    if not (cache_usable() and compiler_available()):
        return False
    key = _source_key(fun, flags)
    if key is not None and library:
        key += ":library"
    with _LOCK:
        if key is None or key in _LOADED or key in _PREFETCHING:
            return False
    cc = c_compiler()
    # what CasADi's shell JIT passes to its compiler (an object it links), or one step to a library
    arguments = [*flags, "-fPIC", "-shared" if library else "-c"]
    try:
        source = _jit_source(fun)
    except RuntimeError:  # no C code for this function: compile_function will say so
        return False
    if os.path.exists(os.path.join(cache_dir(), _library_key(source, arguments, cc) + ".so")):
        return False
    wrapper = os.path.join(os.path.dirname(os.path.abspath(__file__)), "ccache.py")
    process = subprocess.Popen([sys.executable, "-S", "-E", wrapper, cache_dir(), "-", cc, *arguments, source,
                                "-o", source[:-2] + (".so" if library else ".o")],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with _LOCK:
        _PREFETCHING[key] = process
    return True


@contextlib.contextmanager
def compiling_ahead():
    """Within this block :func:`compile_function` starts each compile in the background
    (:func:`prefetch_compile`) and returns the function uncompiled: build the functions a later
    step will compile, without keeping them, so that their compiles overlap the work between."""
    _AHEAD.depth = _ahead_depth() + 1
    try:
        yield
    finally:
        _AHEAD.depth -= 1


def _ahead_depth() -> int:
    """How many ``compiling_ahead`` blocks this thread is in (another thread's compiles stay real)."""
    return getattr(_AHEAD, "depth", 0)


def compiling_ahead_now() -> bool:
    """Whether this thread is inside :func:`compiling_ahead` (compiles go to the background)."""
    return _ahead_depth() > 0


_AHEAD = threading.local()
_SOURCE_NUMBERS = itertools.count()


def compile_function(fun: ca.Function, flags=("-O2",)) -> ca.Function:
    """``fun`` compiled to C by CasADi's JIT, through a persistent cache of compiled libraries.

    The result evaluates compiled code and differentiates through ``fun``'s graph. The
    compiler is :mod:`casest.ccache`, which keys each library on a hash of the generated C
    source, the flags and the compiler's version: a model of the same structure (a fresh
    object, another process, a later session) reuses the library instead of compiling it
    (see :func:`cache_dir`; concurrent processes are safe, corrupt entries are rebuilt).
    Within a process, functions of the same generated source share one compiled Function.
    The JIT's files go to a private temporary folder; the working folder is not changed.
    Without a compiler, or when compiling fails, ``fun`` itself is returned (CasADi's
    virtual machine: slower, same results) with a warning.
    """
    if _ahead_depth():
        prefetch_compile(fun, flags)
        return fun
    name = fun.name()
    key = _source_key(fun, flags)
    with _LOCK:
        if key is not None and key in _LOADED:
            COMPILE_STATS["memory_hits"] += 1
            return _LOADED[key]
        pending = _PREFETCHING.pop(key, None)
    if pending is not None:  # a background process is compiling this very source into the cache
        pending.wait()
    import sys

    cc = c_compiler()
    compiler_id(cc)  # the compiler's version line, part of every cache key (CASEST_CC_ID)
    wrapper = os.path.join(os.path.dirname(os.path.abspath(__file__)), "ccache.py")
    folder = _jit_folder()
    log = os.path.join(folder, "compiles.log")
    command = f'"{sys.executable}" -S -E "{wrapper}" "{cache_dir()}" "{log}" "{cc}"' if cache_usable() else f'"{cc}"'
    try:
        # the JIT writes its source and library into "directory", not the working folder
        compiled = _jit_function(
            fun, {"jit": True, "compiler": "shell", "jit_name": name, "jit_cleanup": False,
                  "jit_options": {"flags": list(flags), "verbose": False, "compiler": command,
                                  "directory": folder + os.sep, "cleanup": False}})
    except (RuntimeError, OSError, ValueError) as err:
        warnings.warn(
            f"compiling {name} to C failed ({str(err).splitlines()[-1][:200]}); using CasADi's "
            "virtual machine instead (slower, same results). Set jit=False to skip the attempt",
            RuntimeWarning,
            stacklevel=2,
        )
        return fun
    COMPILE_STATS["jit_functions"] += 1
    with _LOCK:
        if key is not None:
            _LOADED.setdefault(key, compiled)
            return _LOADED[key]
    return compiled


def compile_library(fun: ca.Function, flags=("-O2",), on_cached=None) -> ca.Function:
    """``fun`` compiled and loaded as a library, through the compile cache; for functions that
    are only evaluated (the result cannot be differentiated), such as the blocks of the sums
    whose data stay outside the graph.

    CasADi's JIT runs two processes for every library, even one the cache holds (the cache's
    compiler wrapper for the object, then the linker). Here the C is the text the JIT would
    write, compiled and linked in one step through the wrapper, and the cache holds the linked
    library under a key computed in this process: a hit is a file check and a ``dlopen``
    (``casadi.external``), no process at all.

    Parameters
    ----------
    fun : casadi.Function
    flags : tuple of str
        Compiler flags (``-fPIC -shared`` are added).
    on_cached : callable, optional
        ``(path, name) -> None``, told the cache's library file and the function's name in it
        once loaded (:func:`casest._casadi.library_index.indexed_library` records them).

    Returns
    -------
    casadi.Function
        The compiled function; without a usable compile cache, :func:`compile_function`'s result
        (CasADi's JIT, or ``fun`` itself with a warning when compiling fails).
    """
    if _ahead_depth():
        prefetch_compile(fun, flags, library=True)
        return fun
    if not (cache_usable() and compiler_available()):
        return compile_function(fun, flags)
    key = _source_key(fun, flags)
    memory_key = None if key is None else key + ":library"
    with _LOCK:
        if memory_key in _LOADED:
            COMPILE_STATS["memory_hits"] += 1
            return _LOADED[memory_key]
        pending = _PREFETCHING.pop(memory_key, None)
    if pending is not None:  # a background process is building this very library into the cache
        pending.wait()
    try:
        source = _jit_source(fun)
    except RuntimeError:  # no C code for this function
        return compile_function(fun, flags)
    path = _cached_or_built_library(fun, source, flags)
    if path is None:
        return compile_function(fun, flags)
    try:
        compiled = ca.external(fun.name() + "_c", path)
    except RuntimeError as err:  # a cached file that is not this library: forget it, build afresh
        _forget_cached(path)
        warnings.warn(f"the compile cache's library for {fun.name()} could not be loaded ({str(err).strip()[-120:]}); "
                      "it was removed and the function is compiled again", RuntimeWarning, stacklevel=2)
        return compile_function(fun, flags)
    if on_cached is not None:
        cached = _library_key(source, [*flags, "-fPIC", "-shared"], c_compiler()) + ".so"
        on_cached(os.path.join(cache_dir(), cached), fun.name() + "_c")
    COMPILE_STATS["jit_functions"] += 1
    with _LOCK:
        if memory_key is None:
            return compiled
        return _LOADED.setdefault(memory_key, compiled)


def library_key(fun: ca.Function, flags=("-O2",)) -> str | None:
    """The in-process key of ``fun``'s linked library (:func:`compile_library`), None without C code.

    Parameters
    ----------
    fun : casadi.Function
    flags : tuple of str

    Returns
    -------
    str or None
    """
    key = _source_key(fun, flags)
    return None if key is None else key + ":library"


def library_state(key: str) -> tuple:
    """``(loaded, compiling)``: the library of ``key`` if this process loaded it, and the background
    process compiling it (:func:`prefetch_compile`), each None when there is none.

    Parameters
    ----------
    key : str
        From :func:`library_key`.

    Returns
    -------
    tuple of (casadi.Function or None, subprocess.Popen or None)
    """
    with _LOCK:
        return _LOADED.get(key), _PREFETCHING.get(key)


def library_in_cache(fun: ca.Function, flags=("-O2",)) -> bool:
    """Whether the compile cache holds a valid linked library of ``fun`` (a :func:`compile_library` hit).

    Parameters
    ----------
    fun : casadi.Function
    flags : tuple of str

    Returns
    -------
    bool
        False as well when ``fun`` has no C code.
    """
    try:
        source = _jit_source(fun)
    except RuntimeError:
        return False
    return ccache.valid(os.path.join(cache_dir(), _library_key(source, [*flags, "-fPIC", "-shared"], c_compiler()) + ".so"))


def take_background_compiles() -> list:
    """The background compiles still registered (:func:`prefetch_compile`), removed from the registry.

    Returns
    -------
    list of subprocess.Popen
    """
    with _LOCK:
        pending = list(_PREFETCHING.values())
        _PREFETCHING.clear()
    return pending


def _forget_cached(path: str) -> None:
    """Remove a library (and its digest) that could not be loaded, where the cache holds it."""
    if os.path.dirname(os.path.abspath(path)) != os.path.abspath(cache_dir()):
        return
    for leftover in (path, path[:-3] + ".sha256"):
        try:
            os.remove(leftover)
        except OSError:
            pass


def _cached_or_built_library(fun: ca.Function, source: str, flags) -> str | None:
    """The path of the linked library of ``source``: the cache's copy, or one built now through the
    cache's compiler wrapper (which stores it); None, with a warning, when the build fails."""
    import subprocess
    import sys

    cc, arguments = c_compiler(), [*flags, "-fPIC", "-shared"]
    cached = os.path.join(cache_dir(), _library_key(source, arguments, cc) + ".so")
    if ccache.valid(cached):
        record_compile("hit")
        return cached
    path = source[:-2] + ".so"
    wrapper = os.path.join(os.path.dirname(os.path.abspath(__file__)), "ccache.py")
    log = os.path.join(_jit_folder(), "compiles.log")
    done = subprocess.run([sys.executable, "-S", "-E", wrapper, cache_dir(), log, cc, *arguments, source, "-o", path],
                          capture_output=True, text=True)
    if done.returncode != 0:
        warnings.warn(f"compiling {fun.name()} to a library failed ({done.stderr.strip()[-200:]}); "
                      "compiling it by CasADi's JIT instead", RuntimeWarning, stacklevel=3)
        return None
    return path
