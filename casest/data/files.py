"""Writing files so that a reader never sees half of one, and never over what is not a file.

Every writer of casest resolves its output path the same way (:func:`output_target`): ``-`` is
standard output; a symbolic link is followed and its target written (the link stays a link);
a path that exists and is not a regular file (a device, a FIFO, a socket, a folder) is
refused, since the atomic rename would replace it with a regular file.
"""

from __future__ import annotations

import os
import stat
import sys
import tempfile

from ..errors import OutputPathError


__all__ = ["atomic_write_text", "output_target", "atomic_replace", "STDOUT"]

#: the output path that means standard output
STDOUT = "-"

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


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
    writes to standard output, a symbolic link's target is written (:func:`output_target`).

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
    shown = os.fspath(path)
    path = output_target(shown)
    if path == STDOUT:
        sys.stdout.write(text)
        sys.stdout.flush()
        return
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
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        atomic_replace(tmp, path, shown)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
