"""Compiled libraries found by what they compute, without building the function to key them.

:func:`~casest._casadi.numerics.compile_library` keys a library by the C source CasADi
generates, so a process must build the function (a ``map`` over a block of samples: 3-21 ms
each on the Pitot model) and generate its C (2-4 ms) before it can find the library the cache
already holds. An *index entry* records, under a key of the function's description (the
per-sample function's serialisation, the block size, the flags, CasADi's version, the
compiler), which cached library holds it; a later process reads the entry and loads the
library directly. A missing, stale or damaged entry only costs the build.
"""

from __future__ import annotations

import hashlib
import os
from typing import Callable

import casadi as ca

from . import ccache
from .numerics import (cache_dir, cache_usable, c_compiler, compile_library, compiler_available, compiler_id,
                       compiling_ahead_now, record_compile)
from .memory import register_memory_cache

__all__ = ["indexed_library", "record_index"]

#: bump when what a description covers changes
_FORMAT = "1"
_LOADED: dict = {}  # index -> loaded Function, forgotten with the other memory caches
register_memory_cache(_LOADED.clear)


def _entry_path(index: str) -> str:
    return os.path.join(cache_dir(), index + ".index")


def _index_key(description: str, flags) -> str:
    h = hashlib.sha256()
    for part in (_FORMAT, ca.__version__, compiler_id(c_compiler()), " ".join(flags), description):
        h.update(part.encode())
        h.update(b"\0")
    return "ix" + h.hexdigest()[:32]


def record_index(index: str, library: str, name: str) -> None:
    """Record (atomically) that the cached library ``library`` holds the function ``name`` of ``index``."""
    if os.path.dirname(os.path.abspath(library)) != os.path.abspath(cache_dir()):
        return  # only libraries the cache keeps
    entry = _entry_path(index)
    temporary = f"{entry}.{os.getpid()}.tmp"
    try:
        with open(temporary, "w") as fh:
            fh.write(os.path.basename(library) + "\n" + name + "\n")
        os.replace(temporary, entry)
    except OSError:
        pass  # an index entry is an optimisation: without one the next process builds the function


def _indexed(index: str) -> ca.Function | None:
    """The library recorded under ``index``, loaded; None when there is no valid entry."""
    try:
        with open(_entry_path(index)) as fh:
            library, name = fh.read().split("\n")[:2]
    except (OSError, ValueError):
        return None
    path = os.path.join(cache_dir(), library)
    if os.sep in library or not ccache.valid(path):
        return None
    try:
        return ca.external(name, path)
    except RuntimeError:
        return None


def indexed_library(description: str, build: Callable[[], ca.Function], flags=("-O2",)) -> ca.Function:
    """``compile_library(build(), flags)``, loaded without calling ``build`` when the cache's index
    holds it.

    Parameters
    ----------
    description : str
        Everything that determines the function ``build`` returns (for example the per-sample
        function's ``serialize()`` and the block size): equal descriptions must give the same
        function.
    build : callable
        ``() -> casadi.Function``, called only when the index has no entry.
    flags : tuple of str
        Compiler flags, as for :func:`~casest._casadi.numerics.compile_library`.

    Returns
    -------
    casadi.Function
        The compiled function (evaluation only, as ``compile_library``'s).
    """
    if not (cache_usable() and compiler_available()) or compiling_ahead_now():
        return compile_library(build(), flags)
    index = _index_key(description, flags)
    if index in _LOADED:
        return _LOADED[index]
    found = _indexed(index)
    if found is not None:
        record_compile("hit")
    else:
        found = compile_library(build(), flags, on_cached=lambda path, name: record_index(index, path, name))
    return _LOADED.setdefault(index, found)
