"""Writing files so that a reader never sees half of one."""

from __future__ import annotations

import os
import tempfile


__all__ = ["atomic_write_text"]


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` so that readers see the old or the new file, never half.

    Writes to a temporary file in the same folder, flushes and fsyncs it, then renames.

    Parameters
    ----------
    path : str or os.PathLike
    text : str

    Returns
    -------
    None
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp_", dir=folder)
    except OSError as err:  # name the user's file, not the temporary one
        raise OSError(err.errno, f"cannot write {path!r} ({err.strerror})", path) from None
    umask = os.umask(0)
    os.umask(umask)
    try:
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the usual permissions
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        try:
            os.replace(tmp, path)
        except OSError as err:  # name the user's file, not the temporary one
            raise OSError(err.errno, f"cannot write {path!r} ({err.strerror})", path) from None
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
