"""casest's in-process caches: per-model structure caches, builds kept on an object, and the
one switch that forgets them all (:func:`clear_memory_caches`; the compile cache on disk stays)."""

from __future__ import annotations

import threading

__all__ = ["BuildCache", "StructureCache", "clear_memory_caches", "register_memory_cache"]


_STRUCTURE_CACHES: list = []


def register_memory_cache(clear) -> None:
    """Have :func:`clear_memory_caches` call ``clear()`` too.

    Parameters
    ----------
    clear : callable
        A cache's own clearing function, called without arguments.
    """
    _CLEARERS.append(clear)


#: clearing functions of the other in-process caches (compiled libraries, designs, ...)
_CLEARERS: list = []


def clear_memory_caches() -> None:
    """Forget every built function, solver and compiled library of this process (not the
    compile cache on disk): the next estimate builds as a fresh process would."""
    for cache in _STRUCTURE_CACHES:
        cache.clear()
    for clear in _CLEARERS:
        clear()


class BuildCache(dict):
    """Builds derived from one object and kept on it (its data-independent functions and
    programs), by key. Not pickled: a copy sent to another process starts empty."""

    def __reduce__(self):
        return (BuildCache, ())

    def get_or_build(self, key, build):
        """The build under ``key``, made on first use (two threads racing both build; one
        result is kept).

        Parameters
        ----------
        key : hashable
        build : callable
            ``build() -> value``.

        Returns
        -------
        object
            The kept build.
        """
        if key not in self:
            self.setdefault(key, build())
        return self[key]


class StructureCache:
    """Per-model caches keyed by the model's structure, not by the object.

    A model exposing ``structure_key`` (a hash of its expressions, scales and bounds) shares
    its entry with every object of the same structure (a fresh ``model()`` from the same
    file, a Monte-Carlo run's copy); other objects are keyed by identity, weakly. At most
    ``max_structures`` structures are kept (the least recently used are dropped).
    """

    def __init__(self, max_structures: int = 16):
        import weakref
        from collections import OrderedDict

        self._by_structure: OrderedDict = OrderedDict()
        self._by_object = weakref.WeakKeyDictionary()
        self._max = int(max_structures)
        self._lock = threading.Lock()
        _STRUCTURE_CACHES.append(self)

    def clear(self) -> None:
        with self._lock:
            self._by_structure.clear()
            self._by_object.clear()

    def setdefault(self, model, default):
        key = getattr(model, "structure_key", None)
        with self._lock:
            if key is None:
                return self._by_object.setdefault(model, default)
            if key in self._by_structure:
                self._by_structure.move_to_end(key)
                return self._by_structure[key]
            self._by_structure[key] = default
            while len(self._by_structure) > self._max:
                self._by_structure.popitem(last=False)
            return default
