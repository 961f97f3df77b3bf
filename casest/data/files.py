"""Writing files so that a reader never sees half of one, and never over what is not a file;
reading only what is a file of a size memory can take.

Every writer of casest resolves its output path the same way: ``-`` is standard output, and a
path that names one of the process's open descriptors (``/dev/stdout``, ``/dev/stderr``,
``/dev/fd/N``, ``/proc/self/fd/N``) is written in place as a stream (:func:`stream_descriptor`:
a shell's ``> file`` or ``>> log`` behind it keeps its meaning; renaming a new file over the
descriptor's target would replace the user's file). Other paths (:func:`output_target`): a
symbolic link is followed and its target written (the link stays a link); a path that exists
and is not a regular file (a device, a FIFO, a socket, a folder) is refused, since the atomic
rename would replace it with a regular file.

Every reader checks its path first (:func:`readable_file`): a device, FIFO or socket can supply
bytes forever (``/dev/zero``) or block without a writer, and a file larger than a share of the
available memory cannot be parsed in it; both are refused before anything is read.
"""

from __future__ import annotations

import os
import re
import stat
import sys
import tempfile

from ..errors import OutputPathError


__all__ = ["atomic_write_text", "atomic_write_bytes", "output_target", "atomic_replace", "stream_descriptor",
           "readable_file", "STDOUT", "INPUT_MEMORY_SHARE"]

#: the output path that means standard output
STDOUT = "-"

#: the largest share of the available memory a file read whole may take (its parsed form takes
#: several times its size)
INPUT_MEMORY_SHARE = 0.25
_DESCRIPTOR_PATH = re.compile(r"^/(?:dev/fd|proc/(?:self|thread-self|(\d+))/fd)/(\d+)$")

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def stream_descriptor(path: str | os.PathLike) -> int | None:
    """The open file descriptor an output path names, written in place (module docstring).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    int or None
        1 for ``-`` and ``/dev/stdout``, 2 for ``/dev/stderr``, N for ``/dev/fd/N`` and
        ``/proc/self/fd/N`` (or this process's own ``/proc/PID/fd/N``); None for a file's path.
    """
    path = os.path.normpath(os.fspath(path)) if os.fspath(path) != STDOUT else STDOUT
    named = {STDOUT: 1, "/dev/stdout": 1, "/dev/stderr": 2}
    if path in named:
        return named[path]
    match = _DESCRIPTOR_PATH.match(path)
    if match is None or (match.group(1) is not None and int(match.group(1)) != os.getpid()):
        return None
    return int(match.group(2))


def _write_stream(descriptor: int, data: bytes, shown: str) -> None:
    """``data`` to an open descriptor, in place (standard output and error through Python's own
    streams, so that earlier printed lines keep their order)."""
    stream = {1: sys.stdout, 2: sys.stderr}.get(descriptor)
    if stream is not None:
        stream.flush()
        if hasattr(stream, "buffer"):
            stream.buffer.write(data)
            stream.buffer.flush()
        else:
            stream.write(data.decode("utf-8", errors="replace"))
            stream.flush()
        return
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(descriptor, view):]
    except OSError as err:
        raise OutputPathError(err.errno, f"cannot write {shown!r} ({err.strerror}): the descriptor is not open "
                                         "for writing in this process", shown) from None


def readable_file(path: str | os.PathLike, what: str, error: type = OSError) -> str:
    """Check that ``path`` names a regular file that memory can take whole (module docstring).

    Parameters
    ----------
    path : str or os.PathLike
    what : str
        What the file is, for the message (``"data file"``, ``"estimate file"``).
    error : type
        The exception to raise (``DataError``, ``ResultFileError``).

    Returns
    -------
    str
        The path.

    Raises
    ------
    error
        When the path does not exist, is not a regular file, or is larger than
        :data:`INPUT_MEMORY_SHARE` of the available memory.
    """
    path = os.fspath(path)
    try:
        mode, size = os.stat(path).st_mode, os.stat(path).st_size
    except FileNotFoundError:
        raise error(f"{what} {path!r} does not exist") from None
    except OSError as err:
        raise error(f"cannot read {what} {path!r} ({err.strerror})") from None
    for is_kind, kind in _KINDS:
        if is_kind(mode):
            fix = "give the file inside it" if stat.S_ISDIR(mode) else \
                "casest reads a whole file, and this may never end or never start; copy the data to a file first"
            raise error(f"{what} {path!r} is {kind}, not a regular file: {fix}")
    available = _available_memory()
    if available and size > INPUT_MEMORY_SHARE * available:
        raise error(f"{what} {path!r} holds {size / 2**20:.0f} MiB, more than {INPUT_MEMORY_SHARE:.0%} of the memory "
                    f"available ({available / 2**20:.0f} MiB) that reading and parsing it whole would need; split "
                    "the record into parts, or use a machine with more memory")
    return path


def _available_memory() -> int | None:
    """Bytes of memory available to a new allocation (None where the system does not say)."""
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def output_target(path: str | os.PathLike) -> str:
    """The file an output path names: a symbolic link's target (resolved), checked to be a regular
    file or not yet there.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    str
        The resolved path to write (``"-"`` as it is).

    Raises
    ------
    OutputPathError
        When the path exists and is not a regular file.
    """
    path = os.fspath(path)
    if path == STDOUT:
        return path
    resolved = os.path.realpath(path)
    try:
        mode = os.stat(resolved).st_mode
    except FileNotFoundError:
        return resolved
    except OSError as err:
        raise OutputPathError(err.errno, f"cannot write {path!r} ({err.strerror})", path) from None
    for is_kind, kind in _KINDS:
        if is_kind(mode):
            shown = path if resolved == os.path.abspath(path) else f"{path!r} (a link to {resolved!r})"
            raise OutputPathError(f"the output path {shown} is {kind}, not a regular file: casest writes a new file "
                                  "there by renaming, which would replace it; give a file's path"
                                  + ("" if stat.S_ISDIR(mode) else ", or - for standard output"))
    return resolved


def atomic_replace(tmp: str, target: str, shown: str) -> None:
    """Rename a finished temporary file onto ``target`` (from :func:`output_target`), naming ``shown``
    in an error."""
    try:
        os.replace(tmp, target)
    except OSError as err:  # name the user's file, not the temporary one
        raise OSError(err.errno, f"cannot write {shown!r} ({err.strerror})", shown) from None


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` so that readers see the old or the new file, never half.

    Writes to a temporary file in the same folder, flushes and fsyncs it, then renames; ``-``
    and the paths of open descriptors (``/dev/stdout``, ``/proc/self/fd/N``) are written in
    place as streams (:func:`stream_descriptor`), a symbolic link's target is written
    (:func:`output_target`).

    Parameters
    ----------
    path : str or os.PathLike
    text : str

    Returns
    -------
    None

    Raises
    ------
    OutputPathError
        When ``path`` names something other than a regular file.
    """
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers see the old or the new file, never half; a
    path naming an open descriptor (``-``, ``/dev/stdout``, ...) is written in place as a stream.

    Parameters
    ----------
    path : str or os.PathLike
    data : bytes

    Returns
    -------
    None

    Raises
    ------
    OutputPathError
        When ``path`` names something other than a regular file or an open descriptor.
    """
    shown = os.fspath(path)
    descriptor = stream_descriptor(shown)
    if descriptor is not None:
        _write_stream(descriptor, data, shown)
        return
    path = output_target(shown)
    folder = os.path.dirname(path)
    try:
        os.makedirs(folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp_", dir=folder)
    except OSError as err:  # name the user's file, not the temporary one
        raise OSError(err.errno, f"cannot write {shown!r} ({err.strerror})", shown) from None
    umask = os.umask(0)
    os.umask(umask)
    try:
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the usual permissions
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        atomic_replace(tmp, path, shown)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
