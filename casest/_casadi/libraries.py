"""Compiled libraries of functions that are evaluated, never differentiated (the blocks of the
sums whose data stay outside the graph): the C that CasADi's JIT would write, compiled and linked
in one step through the compile cache and loaded with ``casadi.external``.

CasADi's JIT runs two processes for every library, even one the cache holds: the cache's compiler
wrapper (a Python process) for the object, then the linker. Here the cache holds the linked
library itself, under a key this process computes (the source's text, the flags, the compiler's
id), so a hit is a file check and a ``dlopen``: no process at all.
"""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import casadi as ca

from . import ccache
from .numerics import (
    _AHEAD,
    _LOADED,
    _LOCK,
    _PREFETCHING,
    COMPILE_STATS,
    _jit_folder,
    _jit_source,
    _library_key,
    _source_key,
    c_compiler,
    cache_dir,
    cache_usable,
    compile_function,
    compiler_available,
    prefetch_compile,
    record_compile,
)

__all__ = ["compile_library"]


def compile_library(fun: ca.Function, flags=("-O2",)) -> ca.Function:
    """``fun`` compiled and loaded as a library, through the compile cache; for functions that
    are only evaluated (the result cannot be differentiated).

    Parameters
    ----------
    fun : casadi.Function
    flags : tuple of str
        Compiler flags (``-fPIC -shared`` are added).

    Returns
    -------
    casadi.Function
        The compiled function; without a usable compile cache, :func:`compile_function`'s result
        (CasADi's JIT, or ``fun`` itself with a warning when compiling fails).
    """
    if _AHEAD:
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
    cc, arguments = c_compiler(), [*flags, "-fPIC", "-shared"]
    cached = os.path.join(cache_dir(), _library_key(source, arguments, cc) + ".so")
    if ccache._valid(cached):
        record_compile("hit")
        path = cached
    else:
        path = source[:-2] + ".so"
        wrapper = os.path.join(os.path.dirname(os.path.abspath(__file__)), "ccache.py")
        log = os.path.join(_jit_folder(), "compiles.log")
        done = subprocess.run([sys.executable, "-S", "-E", wrapper, cache_dir(), log, cc, *arguments, source,
                               "-o", path], capture_output=True, text=True)
        if done.returncode != 0:
            warnings.warn(f"compiling {fun.name()} to a library failed ({done.stderr.strip()[-200:]}); "
                          "compiling it by CasADi's JIT instead", RuntimeWarning, stacklevel=2)
            return compile_function(fun, flags)
    compiled = ca.external(fun.name() + "_c", path)
    COMPILE_STATS["jit_functions"] += 1
    with _LOCK:
        if memory_key is None:
            return compiled
        return _LOADED.setdefault(memory_key, compiled)
