"""The command line's output paths: checked before any work is done, and standard output taken."""

from __future__ import annotations

import os
import tempfile

from ..data.files import output_target, stream_descriptor
from ..errors import CasestError, OutputPathError

__all__ = ["UsageError", "check_output_path", "stdout_taken", "FIGURE_FORMATS"]


class UsageError(CasestError, ValueError):
    """Options that cannot work together or point at the wrong place."""


def _replaceable(path: str, folder: str) -> bool:
    """Whether an existing file can be replaced (written to a temporary file, then renamed over it)."""
    import stat

    if not os.access(path, os.W_OK):
        return False
    sticky = os.stat(folder).st_mode & stat.S_ISVTX  # /tmp: only the owner may rename over a file
    return not (sticky and os.geteuid() != 0 and os.stat(path).st_uid != os.geteuid())


#: the extensions matplotlib writes a figure as (Agg, PDF, PS and SVG backends)
FIGURE_FORMATS = frozenset({"png", "pdf", "svg", "svgz", "eps", "ps", "jpg", "jpeg", "tif", "tiff", "webp"})


def check_output_path(path: str | None, option: str, inputs: dict) -> None:
    """Refuse, before any work is done, an output path that cannot be written or that would
    replace one of the ``inputs``.

    Parameters
    ----------
    path : str or None
        The output path (None: the option was not given; ``-`` or an open descriptor's path is
        written as a stream and not checked).
    option : str
        The command-line option, for the message.
    inputs : dict
        Option -> path of the files the command reads.

    Raises
    ------
    UsageError
        A folder, a figure extension no backend writes, a device or FIFO, a missing folder, one of
        the inputs, a file this user cannot replace, a folder that cannot be written.
    """
    if path is None or stream_descriptor(path) is not None:  # written in place as a stream
        return
    if os.path.isdir(path):
        raise UsageError(f"{option} {path!r} is a folder; give a file name, e.g. {os.path.join(path, 'estimate.json')}")
    suffix = os.path.splitext(path)[1].lower().lstrip(".")
    if option == "--figure" and suffix and suffix not in FIGURE_FORMATS:
        raise UsageError(f"--figure {path!r}: no figure is written as .{suffix}; name it .png (or one of "
                         f"{', '.join(sorted(FIGURE_FORMATS))})")
    try:
        path = output_target(path)  # a link's target; a device, FIFO or socket refused
    except OutputPathError as err:
        raise UsageError(f"{option}: {err}") from None
    folder = os.path.dirname(path)
    if not os.path.isdir(folder):
        raise UsageError(f"{option} {path!r}: the folder {folder!r} does not exist; create it first")
    for source, other in inputs.items():
        if other is not None and os.path.realpath(other) == os.path.realpath(path):
            raise UsageError(f"{option} {path!r} is the file given with {source}: writing would replace it; "
                             "choose another name")
    if os.path.exists(path) and not _replaceable(path, folder):
        raise UsageError(f"{option} {path!r} exists and cannot be replaced by this user (it is not writable, or it "
                         "belongs to another user in a shared folder); choose another name")
    try:  # a probe in the folder: permissions, a read-only file system, a full disk
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".casest_probe_"):
            pass
    except OSError as err:
        raise UsageError(f"{option} {path!r} cannot be written: {err.strerror} in {folder!r}") from None


def stdout_taken(*paths) -> bool:
    """Whether one of the outputs is standard output (``-``, ``/dev/stdout``): then it alone goes
    there, so that ``> file`` or a pipe receives only it.

    Parameters
    ----------
    *paths : str or None
        The command's output paths.

    Returns
    -------
    bool
    """
    return any(p is not None and stream_descriptor(p) == 1 for p in paths)
