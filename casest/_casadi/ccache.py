"""A caching C compiler for CasADi's JIT: ``python ccache.py CACHE_DIR LOG CC [compiler arguments]``.

CasADi's ``shell`` JIT runs ``<compiler> <flags> <source.c> -o <library.so>``. This wrapper
keys the library on a hash of the source, the flags and the compiler's version line: on a
hit it copies the cached library to the requested output; on a miss it runs the compiler,
then stores the library under the key (written to a temporary name and renamed, with a
digest of its bytes and its entry's name beside it; concurrent processes lock the entry while
one compiles it). A cached library whose digest no longer matches (damaged, or another entry's
copied over it), or an ELF library whose mapped parts run past its end (truncated), is rebuilt. Libraries are taken from and stored in the
cache only where the folder and the files belong to this user and no one else can write them
(as ssh checks its keys): otherwise, or where the cache cannot be written (a full disk), the
source is compiled straight to the requested output. It imports nothing from casest, so it
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


def entry_digest(so_path: str, data: bytes) -> str:
    """The digest an entry's ``.sha256`` records: of the library's bytes bound to its entry's
    name, so that a library copied under another entry's name with that entry's digest file
    does not match (hex)."""
    h = hashlib.sha256(os.path.basename(so_path)[:-3].encode() + b"\0")
    h.update(data)
    return h.hexdigest()


def trusted(path: str) -> bool:
    """Whether ``path`` belongs to this user and no one else can write it (True where the system
    has no user ids)."""
    if not hasattr(os, "getuid"):
        return True
    try:
        info = os.stat(path)
    except OSError:
        return False
    return info.st_uid == os.getuid() and not info.st_mode & 0o022


def valid(so_path: str) -> bool:
    """Whether the cached library is this user's alone, its digest file matches it, and (an ELF
    library) every part the loader maps lies inside the file: a truncated library whose digest
    was written again to match would otherwise be mapped past its end (a bus error)."""
    digest = so_path[:-3] + ".sha256"
    if not (trusted(so_path) and trusted(digest)):
        return False
    try:
        with open(digest, encoding="ascii") as fh:
            recorded = fh.read().strip()
        with open(so_path, "rb") as fh:
            data = fh.read()
    except OSError:
        return False
    return recorded == entry_digest(so_path, data) and elf_complete(data)


def elf_complete(data: bytes) -> bool:
    """Whether an ELF file's bytes hold every segment its program headers and the section table
    its header name (True for a file that is not ELF: other formats are not checked).

    Parameters
    ----------
    data : bytes
        The file's content.

    Returns
    -------
    bool
    """
    import struct

    if data[:4] != b"\x7fELF":
        return True
    if len(data) < 52 or data[4] not in (1, 2) or data[5] not in (1, 2):
        return False
    wide, order = data[4] == 2, "<" if data[5] == 1 else ">"
    head = struct.Struct(order + ("QQ" if wide else "II"))  # e_phoff, e_shoff
    counts = struct.Struct(order + "HHHH")  # e_phentsize, e_phnum, e_shentsize, e_shnum
    if len(data) < (64 if wide else 52):
        return False
    phoff, shoff = head.unpack_from(data, 0x20 if wide else 0x1C)
    phentsize, phnum, shentsize, shnum = counts.unpack_from(data, 0x36 if wide else 0x2A)
    if phoff + phentsize * phnum > len(data) or (shnum and shoff + shentsize * shnum > len(data)):
        return False
    segment = struct.Struct(order + ("IIQQQQ" if wide else "IIIIII"))  # up to p_filesz
    for k in range(phnum):
        fields = segment.unpack_from(data, phoff + k * phentsize)
        offset, filesz = (fields[2], fields[5]) if wide else (fields[1], fields[4])
        if fields[0] and offset + filesz > len(data):  # a segment (PT_NULL aside) past the end
            return False
    return True


def _compile_straight(cc: str, flags: list, sources: list, out: str) -> int:
    """Compile without the cache."""
    import subprocess

    return subprocess.run([cc, *flags, *sources, "-o", out]).returncode


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
        os.makedirs(folder, mode=0o700, exist_ok=True)
    except OSError:  # no cache here: compile straight to the output (the caller has warned)
        return _compile_straight(cc, flags, sources, out)
    if not trusted(folder):  # another user could plant a library here (the caller has warned)
        return _compile_straight(cc, flags, sources, out)
    so_path = os.path.join(folder, key + ".so")
    try:
        _fill(so_path, cc, flags, sources, log)
        _copy(so_path, out)
    except OSError:  # the cache cannot be written (a full disk): the library straight to the output
        _log_quietly(log, "uncached")
        return _compile_straight(cc, flags, sources, out)
    return 0


def _fill(so_path: str, cc: str, flags: list, sources: list, log: str) -> None:
    """The cache entry: a hit, or compiled (rebuilt where its digest no longer matches) under a lock.
    Raises OSError where the compiler fails or the cache cannot be written."""
    if valid(so_path):
        _log(log, "hit")
        return
    with _Lock(so_path[:-3] + ".lock"):
        if valid(so_path):  # built by another process meanwhile
            _log(log, "hit")
            return
        rebuilt = os.path.exists(so_path)
        tag = f".{os.getpid()}.tmp"
        tmp_so, tmp_sha = so_path + tag, so_path[:-3] + ".sha256" + tag
        import subprocess

        try:
            result = subprocess.run([cc, *flags, *sources, "-o", tmp_so])
            if result.returncode != 0:
                raise OSError(f"the compiler ended with {result.returncode}")
            with open(tmp_so, "rb") as fh:
                built = fh.read()
            with open(tmp_sha, "w", encoding="ascii") as fh:
                fh.write(entry_digest(so_path, built))
            os.chmod(tmp_so, 0o755)  # no group or other write, whatever the umask: trusted() on the next hit
            os.chmod(tmp_sha, 0o644)
            os.replace(tmp_so, so_path)
            os.replace(tmp_sha, so_path[:-3] + ".sha256")
        finally:
            for leftover in (tmp_so, tmp_sha):
                try:
                    os.remove(leftover)
                except OSError:
                    pass
        _log(log, "rebuilt" if rebuilt else "compiled")


def _log_quietly(path: str, event: str) -> None:
    try:
        _log(path, event)
    except OSError:
        pass


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
