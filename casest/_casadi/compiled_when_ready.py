"""Functions evaluated uncompiled until their compiled library is at hand.

Small problems should never wait for a C compiler, and should not pay CasADi's virtual
machine forever either: :class:`CompiledWhenReady` evaluates uncompiled until the compile
cache holds the function's library (from an earlier session, or from a background compile
started once the uncompiled evaluations have cost :data:`COMPILE_AFTER_SECONDS`).
"""

from __future__ import annotations

import atexit

import casadi as ca

from .numerics import (cache_usable, compile_library, compiler_available, library_in_cache, library_key,
                       library_state, prefetch_compile, take_background_compiles)

__all__ = ["CompiledWhenReady", "COMPILE_AFTER_SECONDS", "EXIT_WAIT_SECONDS"]


#: uncompiled evaluation time (s) of a function after which its library is compiled in the background
COMPILE_AFTER_SECONDS = 0.5
#: how long the process's exit waits for a background compile to store its library (s)
EXIT_WAIT_SECONDS = 30.0


def _finish_background_compiles() -> None:
    """At exit: let each background compile store its library (bounded), so that none is orphaned."""
    import subprocess

    for process in take_background_compiles():
        try:
            process.wait(timeout=EXIT_WAIT_SECONDS)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


atexit.register(_finish_background_compiles)


class CompiledWhenReady:
    """A function evaluated by CasADi's virtual machine until its compiled library is at hand.

    The compiled library is used as soon as this process or the compile cache holds it (a
    later solve, a later estimate, a later session). Its compile starts in the background
    (:func:`prefetch_compile`, another core) once the uncompiled evaluations reported by
    :meth:`spent` add up to :data:`COMPILE_AFTER_SECONDS`: small problems never wait for a
    compiler, and a compile runs only where it pays.

    Parameters
    ----------
    fun : casadi.Function
    flags : tuple of str
        Compiler flags (``-fPIC -shared`` are added).
    """

    def __init__(self, fun: ca.Function, flags=("-O2",)):
        self.fun, self.flags = fun, tuple(flags)
        self._compiled: ca.Function | None = None
        self._key: str | None = None
        self._usable = cache_usable() and compiler_available()
        self._seconds = 0.0
        self._started = False
        self._looked = False

    def get(self) -> ca.Function:
        """The compiled function if its library is ready, else the uncompiled one.

        Returns
        -------
        casadi.Function
        """
        if self._compiled is not None or not self._usable:
            return self._compiled or self.fun
        if self._key is None:
            self._key = library_key(self.fun, self.flags)
            if self._key is None:  # no C code for this function
                self._usable = False
                return self.fun
        loaded, pending = library_state(self._key)
        if loaded is not None:
            self._compiled = loaded
        elif pending is not None and pending.poll() is not None:  # a background compile has ended
            self._compiled = self._from_cache()
            self._usable = self._compiled is not None
        elif pending is None and not self._looked:  # once: a library from an earlier session
            self._looked = True
            self._compiled = self._from_cache()
        return self._compiled or self.fun

    def spent(self, seconds: float) -> None:
        """Report ``seconds`` of uncompiled evaluation; past :data:`COMPILE_AFTER_SECONDS` in all, the
        library's compile starts in the background.

        Parameters
        ----------
        seconds : float
        """
        self._seconds += seconds
        if self._usable and not self._started and self._compiled is None and self._seconds >= COMPILE_AFTER_SECONDS:
            self._started = True
            prefetch_compile(self.fun, self.flags, library=True)

    def compile_now(self) -> ca.Function:
        """Compile (or load) the library now and use it from here on (what a later session finds in the
        compile cache).

        Returns
        -------
        casadi.Function
        """
        if self._usable:
            self._compiled = compile_library(self.fun, self.flags)
        return self._compiled or self.fun

    def _from_cache(self) -> ca.Function | None:
        """The library from the compile cache (a hit: a file check and a load), None if it is not there."""
        return compile_library(self.fun, self.flags) if library_in_cache(self.fun, self.flags) else None
