"""The compile cache's folder: where it is, whether it can be used (and why not), what it holds,
and clearing it."""

from __future__ import annotations

import contextlib
import os
import warnings

from .ccache import trusted

__all__ = ["cache_dir", "cache_usable", "cache_info", "clear_cache"]


_CACHE_STATE: dict = {}


def cache_usable() -> bool:
    """Whether the compile cache folder can be created and written, and is this user's alone (as
    ssh checks its keys: no other user can plant a library there; checked once per process); if
    not, warn once naming the folder and the cause, and compile without the cache."""
    folder = cache_dir()
    if folder not in _CACHE_STATE:
        try:
            os.makedirs(folder, mode=0o700, exist_ok=True)
            probe = os.path.join(folder, f".probe_{os.getpid()}")
            with open(probe, "w", encoding="ascii"):
                pass
            os.remove(probe)
            _CACHE_STATE[folder] = trusted(folder)
            if not _CACHE_STATE[folder]:
                warnings.warn(f"the compile cache folder {folder!r} belongs to another user or others can write it: "
                              "a library planted there would run inside this process, so it is not used (each "
                              "process compiles again); make it yours alone (chmod go-w) or set CASEST_CACHE_DIR to "
                              "a folder of your own", RuntimeWarning, stacklevel=3)
        except OSError as err:
            _CACHE_STATE[folder] = False
            warnings.warn(f"the compile cache folder {folder!r} cannot be used ({err.strerror}): compiling without "
                          "the cache (each process compiles again); set CASEST_CACHE_DIR to a writable folder",
                          RuntimeWarning, stacklevel=3)
    return _CACHE_STATE[folder]


def cache_dir() -> str:
    """The folder of compiled functions: ``$CASEST_CACHE_DIR``, else the user's cache folder.

    The user's cache folder comes from ``platformdirs`` when installed (``~/.cache/casest`` on
    Linux), else ``$XDG_CACHE_HOME/casest`` or ``~/.cache/casest``.
    """
    env = os.environ.get("CASEST_CACHE_DIR")
    if env:
        return env
    # found once per value of the variables it reads (platformdirs' lookup costs a tenth of a
    # millisecond, and every estimate of a small problem asks)
    key = (os.environ.get("XDG_CACHE_HOME"), os.environ.get("HOME"))
    if key not in _CACHE_FOLDERS:
        try:
            import platformdirs

            base = platformdirs.user_cache_dir("casest")
        except ImportError:
            base = os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"),
                                "casest")
        _CACHE_FOLDERS[key] = os.path.join(base, "compiled")
    return _CACHE_FOLDERS[key]


_CACHE_FOLDERS: dict = {}


def clear_cache() -> int:
    """Delete every compiled function in :func:`cache_dir`; returns the number of files removed."""
    folder = cache_dir()
    if not os.path.isdir(folder):
        return 0
    removed = 0
    for name in os.listdir(folder):
        # the libraries, their digests and locks, leftovers, and the markers of sums compiled ahead
        if name.endswith((".so", ".sha256", ".lock")) or ".tmp" in name or ".part" in name or name.startswith("ahead_"):
            with contextlib.suppress(OSError):
                os.remove(os.path.join(folder, name))
                removed += 1
    return removed


def cache_info() -> dict:
    """The cache folder, its number of compiled functions, their size in bytes, and what keeps the
    folder from being used (``"problem"``: empty when it is usable or not made yet)."""
    folder = cache_dir()
    files = [f for f in os.listdir(folder) if f.endswith(".so")] if os.path.isdir(folder) else []
    size = sum(os.path.getsize(os.path.join(folder, f)) for f in files)
    return {"folder": folder, "functions": len(files), "bytes": size, "problem": _cache_folder_problem(folder)}


def _cache_folder_problem(folder: str) -> str:
    """Why a cache folder cannot be used, in words ("" when it can, or can be made)."""
    if os.path.islink(folder) and not os.path.exists(folder):
        return f"it is a link to {os.path.realpath(folder)!r}, which does not exist"
    if os.path.exists(folder) and not os.path.isdir(folder):
        return "it is a file, not a folder"
    if os.path.isdir(folder) and not os.access(folder, os.W_OK | os.X_OK):
        return "this user cannot write it"
    if os.path.isdir(folder) and not trusted(folder):
        return "another user owns it or others can write it"
    return ""
