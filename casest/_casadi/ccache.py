"""A caching C compiler for CasADi's JIT: ``python ccache.py CACHE_DIR LOG CC [compiler arguments]``.

CasADi's ``shell`` JIT runs ``<compiler> <flags> <source.c> -o <library.so>``. This wrapper
keys the library on a hash of the source, the flags and the compiler's version line: on a
hit it copies the cached library to the requested output; on a miss it runs the compiler,
then stores the library under the key (written to a temporary name and renamed, with a
digest beside it; concurrent processes lock the entry while one compiles it). A cached
library whose digest no longer matches is rebuilt. It imports nothing from casest, so it
starts in milliseconds (run with ``python -S -E``).

Each outcome (``hit``, ``compiled``, ``rebuilt``) is appended as a line to the file LOG
(``-``: none), for tests and benchmarks.
"""

from __future__ import annotations

import hashlib
import os
import sys


# subprocess, shutil and contextlib cost 5-14 ms each to import; a cache hit needs none of
# them (it runs once per compiled function, in a process of its own)


def file_digest(path: str) -> str:
    """The SHA-256 of a file's bytes (hex)."""
    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()


def valid(so_path: str) -> bool:
    """Whether the cached library's digest file matches it."""
    try:
        with open(so_path[:-3] + ".sha256", encoding="ascii") as fh:
            return fh.read().strip() == file_digest(so_path)
    except OSError:
        return False


class _Lock:
    """An exclusive lock on ``path`` (fcntl; none where fcntl does not exist)."""

    def __init__(self, path: str):
        self.path, self.fh = path, None

    def __enter__(self):
        try:
            import fcntl
        except ImportError:
            return self
        self.fh = open(self.path, "a")
        fcntl.flock(self.fh, fcntl.LOCK_EX)
        return self

    def __exit__(self, *exc):
        if self.fh is not None:
            import fcntl

            fcntl.flock(self.fh, fcntl.LOCK_UN)
            self.fh.close()


def _copy(source: str, target: str) -> None:
    with open(source, "rb") as src, open(target, "wb") as dst:
        dst.write(src.read())


def _log(path: str, event: str) -> None:
    if path != "-":
        with open(path, "a", encoding="ascii") as fh:
            fh.write(event + "\n")


def main(argv: list[str]) -> int:
    folder, log, cc, args = argv[0], argv[1], argv[2], argv[3:]
    out = args[args.index("-o") + 1]
    sources = [a for a in args if a.endswith((".c", ".cpp"))]
    flags = [a for i, a in enumerate(args) if a not in sources and a != "-o" and (i == 0 or args[i - 1] != "-o")]
    version = os.environ.get("CASEST_CC_ID")  # the caller's, measured once per process
    if not version:
        import subprocess

        try:
            version = subprocess.run([cc, "--version"], capture_output=True, text=True).stdout.splitlines()[0]
        except (OSError, IndexError):
            version = cc
    h = hashlib.sha256()
    for src in sources:
        with open(src, "rb") as fh:
            h.update(fh.read())
    h.update("\0".join(flags + [version]).encode())
    key = h.hexdigest()[:32]
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError:  # no cache here: compile straight to the output (the caller has warned)
        import subprocess

        return subprocess.run([cc, *flags, *sources, "-o", out]).returncode
    so_path = os.path.join(folder, key + ".so")
    if not valid(so_path):
        with _Lock(so_path[:-3] + ".lock"):
            if not valid(so_path):  # not built by another process meanwhile
                rebuilt = os.path.exists(so_path)
                tag = f".{os.getpid()}.tmp"
                tmp_so, tmp_sha = so_path + tag, so_path[:-3] + ".sha256" + tag
                import subprocess

                try:
                    result = subprocess.run([cc, *flags, *sources, "-o", tmp_so])
                    if result.returncode != 0:
                        return result.returncode
                    with open(tmp_sha, "w", encoding="ascii") as fh:
                        fh.write(file_digest(tmp_so))
                    os.replace(tmp_so, so_path)
                    os.replace(tmp_sha, so_path[:-3] + ".sha256")
                finally:
                    for leftover in (tmp_so, tmp_sha):
                        try:
                            os.remove(leftover)
                        except OSError:
                            pass
                _log(log, "rebuilt" if rebuilt else "compiled")
            else:
                _log(log, "hit")
    else:
        _log(log, "hit")
    _copy(so_path, out)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
