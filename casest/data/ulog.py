"""PX4 ULog flight logs (``Dataset.from_ulog``): chosen topics and fields, read with the
``pyulog`` package (``pip install 'casest[logs]'``), aligned onto one time base.

Each topic of a ULog is logged at its own, irregular rate with its own ``timestamp`` (us).
The columns are put on one time base, within the span every chosen topic covers:

- by default the time stamps of the chosen topic with the most samples (as logged);
- ``time_base="topic"``: that topic's time stamps;
- ``sample_time=dt``: a uniform grid of step dt (s).

A continuous signal is interpolated linearly between its own samples; a discrete one (a
mode, a flag, a counter: listed in ``hold``) keeps its last logged value (zero-order hold).
Each column's alignment is recorded in :attr:`Dataset.alignment` and stated in an estimate's
notes. A field is named ``"topic.field"`` (``"vehicle_angular_velocity.xyz[0]"``); a topic
logged by several instances takes its instance as ``"topic[1].field"`` (``multi_id``, 0 by
default).
"""

from __future__ import annotations

import difflib
import os
import warnings
import re
from dataclasses import dataclass
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from ..checks import positive_number
from ..errors import DataError
from .files import readable_file
from .matfile import mat_columns_needed
from .units import convert_to_model_units


__all__ = ["AlignedColumn", "UlogColumns", "read_ulog_columns"]

_FIELD = re.compile(r"^\s*([A-Za-z_]\w*)\s*(?:\[\s*(\d+)\s*\])?\s*\.\s*(\S.*?)\s*$")


@dataclass(frozen=True)
class AlignedColumn:
    """How one column was put on the data set's time base.

    Attributes
    ----------
    source : str
        ``"topic[multi_id].field"`` in the log.
    method : {"interpolated", "held"}
        Linear interpolation between the topic's samples, or its last value held.
    source_rate : float
        The topic's mean logging rate over the aligned span (Hz).
    largest_gap : float
        The topic's longest interval between samples inside the aligned span (s).
    """

    source: str
    method: str
    source_rate: float
    largest_gap: float

    def describe(self) -> str:
        """One line: source, method, rate and the largest gap."""
        return (f"{self.source} {self.method} from {self.source_rate:.4g} Hz "
                f"(largest gap {self.largest_gap:.3g} s)")


class UlogColumns(NamedTuple):
    """The columns read from a ULog, on one time base, in the model's units where it declares them."""

    arrays: dict
    undeclared_units: dict
    alignment: dict


def read_ulog_columns(model, path: str | os.PathLike, fields: Mapping[str, str], *,
                      sample_time: float | None = None, time_base: str | None = None,
                      hold: Sequence[str] = (), extra: Sequence[str] = (),
                      units: Mapping[str, str] | None = None) -> UlogColumns:
    """Read a model's columns from a PX4 ULog and align them onto one time base.

    Parameters
    ----------
    model : Model or DynamicModel
        Its signals and outputs (and the states started from the data) are the columns read;
        a dynamic model's time column is the time base, in s from its first instant.
    path : str or path-like
    fields : mapping of str to str
        Column name -> ``"topic.field"`` or ``"topic[multi_id].field"``; every column the
        model needs (besides its time) and every ``extra`` column.
    sample_time : float, optional
        Align onto a uniform grid of this step (s).
    time_base : str, optional
        Align onto the time stamps of this topic (``"topic"`` or ``"topic[multi_id]"``).
    hold : sequence of str
        Columns that are discrete (modes, flags, counters): their last value is held.
    extra : sequence of str
        Further columns to read (kept in :attr:`Dataset.extra`). A static model's time base
        is kept as the extra column ``"time"`` (s).
    units : mapping of str to str, optional
        The unit of a column in the log, converted to the model's unit (pint).

    Returns
    -------
    UlogColumns
        ``arrays`` (each shape (N,)), ``undeclared_units`` and ``alignment`` (column ->
        :class:`AlignedColumn`).

    Raises
    ------
    DataError
        pyulog missing, a missing or unreadable file, a topic, instance or field the log does
        not hold (with the names that are), a column without a field, topics whose spans do
        not overlap, both ``sample_time`` and ``time_base``.
    """
    log = _open(os.fspath(path))
    time = getattr(model, "time", None)
    names = [n for n in mat_columns_needed(model, extra) if n != time]
    fields = dict(fields)
    missing = [n for n in names if n not in fields]
    if missing:
        raise DataError(f"fields= gives no log field for columns {missing}; map each to 'topic.field' (for example "
                        f"{{{missing[0]!r}: 'vehicle_angular_velocity.xyz[0]'}})")
    unknown = sorted(set(fields) - set(names))
    if unknown:
        raise DataError(f"fields= names {unknown}, which are not columns of the model ({names}); to keep other "
                        "columns, list them in extra=")
    unknown_hold = sorted(set(hold) - set(names))
    if unknown_hold:
        raise DataError(f"hold= names {unknown_hold}, which are not columns read ({names})")
    series = {name: _series(log, name, fields[name], path) for name in names}
    grid = _time_base(log, series, sample_time, time_base, path)
    arrays, alignment = {}, {}
    for name, (source, stamps, values) in series.items():
        method = "held" if name in hold else "interpolated"
        arrays[name] = _align(stamps, values, grid, method)
        alignment[name] = _record(source, stamps, grid, method)
    seconds = (grid - grid[0]) * 1e-6
    if time is not None:
        arrays[time] = seconds
    elif "time" not in arrays:
        arrays["time"] = seconds
    undeclared = convert_to_model_units(model, arrays, dict(units or {}), os.fspath(path))
    return UlogColumns(arrays, undeclared, alignment)


def _open(path: str):
    try:
        from pyulog import ULog
    except ImportError:
        raise DataError("reading ULog files needs the pyulog package: pip install 'casest[logs]'") from None
    if os.path.isdir(path):
        raise DataError(f"{path!r} is a folder, not a ULog file; give the path of the .ulg file inside it")
    readable_file(path, "ULog file", DataError)
    try:
        log = ULog(path)
    except Exception as err:  # pyulog raises bare exceptions of several kinds on a damaged file
        raise DataError(f"{path}: not a readable ULog file ({type(err).__name__}: {err})") from None
    if getattr(log, "file_corruption", False):
        warnings.warn(f"{path}: the ULog file is damaged (pyulog skipped corrupt data): the topics may miss samples "
                      "in the damaged part; check each column's time stamps (Dataset.alignment) or use an intact copy",
                      RuntimeWarning, stacklevel=4)
    missing = bytes_missing_at_the_end(path)
    if missing:
        warnings.warn(f"{path}: the ULog file ends inside a message ({missing} byte(s) of its last message are "
                      "missing): it was cut short (an interrupted copy or download, a full card), and each topic ends "
                      "at its last whole message; use a complete copy, or check that the record's end is the one "
                      "you expect (Dataset.time)", RuntimeWarning, stacklevel=4)
    return log


#: the bytes of a ULog file's header, before its first message, and of each message's header
ULOG_HEADER_BYTES, MESSAGE_HEADER_BYTES = 16, 3


def bytes_missing_at_the_end(path: str) -> int:
    """How many bytes the last message of a ULog file lacks (0: the file ends where a message does).

    Every ULog message after the 16-byte file header starts with its size (uint16, little-endian)
    and type (uint8); walking them from the first, a complete file ends exactly at the end of
    its last message.

    Parameters
    ----------
    path : str

    Returns
    -------
    int
    """
    with open(path, "rb") as fh:
        raw = fh.read()
    position, size = ULOG_HEADER_BYTES, len(raw)
    while position + MESSAGE_HEADER_BYTES <= size:
        position += MESSAGE_HEADER_BYTES + int.from_bytes(raw[position:position + 2], "little")
    if position >= size:
        return position - size
    return MESSAGE_HEADER_BYTES - (size - position)  # cut inside a message's header


def _topic(log, topic: str, multi_id: int, column: str, path):
    instances = {(d.name, d.multi_id): d for d in log.data_list}
    if (topic, multi_id) in instances:
        return instances[(topic, multi_id)]
    topics = sorted({d.name for d in log.data_list})
    if topic in topics:
        ids = sorted(m for n, m in instances if n == topic)
        raise DataError(f"{path}: topic {topic!r} has no instance {multi_id} (column {column!r}); it has multi_id "
                        f"{ids}: write '{topic}[k].field'")
    close = difflib.get_close_matches(topic, topics, n=3)
    hint = f" (did you mean {' or '.join(map(repr, close))}?)" if close else ""
    raise DataError(f"{path}: the log has no topic {topic!r} (column {column!r}){hint}; it holds {len(topics)} "
                    f"topics: {', '.join(topics)}")


def _series(log, column: str, where: str, path) -> tuple:
    """(source, time stamps in us, values) of one column's log field."""
    match = _FIELD.match(str(where))
    if not match:
        raise DataError(f"{path}: {where!r} (column {column!r}) is not a log field; write 'topic.field' or "
                        "'topic[multi_id].field'")
    topic, multi_id, field = match.group(1), int(match.group(2) or 0), match.group(3)
    entry = _topic(log, topic, multi_id, column, path)
    if field not in entry.data or field == "timestamp":
        available = [f for f in entry.data if f != "timestamp"]
        close = difflib.get_close_matches(field, available, n=3)
        hint = f" (did you mean {' or '.join(map(repr, close))}?)" if close else ""
        raise DataError(f"{path}: topic {topic!r} has no field {field!r} (column {column!r}){hint}; its fields: "
                        f"{', '.join(available)}")
    stamps = np.asarray(entry.data["timestamp"], dtype=float)
    values = np.asarray(entry.data[field], dtype=float)
    order = np.argsort(stamps, kind="stable")
    stamps, values = stamps[order], values[order]
    keep = np.concatenate([[True], np.diff(stamps) > 0])  # a repeated time stamp keeps its first value
    if keep.sum() < 2:
        raise DataError(f"{path}: topic {topic!r} holds {int(keep.sum())} distinct time stamp(s) (column "
                        f"{column!r}); at least two are needed to align it")
    return f"{topic}[{multi_id}].{field}", stamps[keep], values[keep]


def _time_base(log, series: dict, sample_time, time_base, path) -> np.ndarray:
    """The common time stamps (us): inside every column's span."""
    if sample_time is not None and time_base is not None:
        raise DataError("give sample_time= (a uniform grid) or time_base= (a topic's time stamps), not both")
    start = max(s[1][0] for s in series.values())
    stop = min(s[1][-1] for s in series.values())
    if not start < stop:
        spans = ", ".join(f"{name}: {s[1][0] * 1e-6:.3f}-{s[1][-1] * 1e-6:.3f} s" for name, s in series.items())
        raise DataError(f"{path}: the chosen fields' time spans do not overlap ({spans}); choose fields logged "
                        "over a common interval")
    if sample_time is not None:
        sample_time = positive_number(sample_time, "sample_time", error=DataError, meaning="the grid's interval")
        return start + np.arange(int(np.floor((stop - start) / (sample_time * 1e6) + 1e-9)) + 1) * sample_time * 1e6
    if time_base is not None:
        stamps = _topic_stamps(log, time_base, path)
    else:
        stamps = max(series.values(), key=lambda s: s[1].size)[1]
    grid = stamps[(stamps >= start) & (stamps <= stop)]
    if grid.size < 2:
        raise DataError(f"{path}: the time base has {grid.size} sample(s) inside the chosen fields' common span; "
                        "choose another time_base or give sample_time")
    return grid


def _topic_stamps(log, time_base: str, path) -> np.ndarray:
    """The distinct time stamps (us) of the topic ``time_base`` names (``topic`` or ``topic[multi_id]``)."""
    match = re.match(r"^\s*([A-Za-z_]\w*)\s*(?:\[\s*(\d+)\s*\])?\s*$", str(time_base))
    if not match:
        raise DataError(f"time_base={time_base!r} is not a topic; write 'topic' or 'topic[multi_id]'")
    entry = _topic(log, match.group(1), int(match.group(2) or 0), "time_base", path)
    return np.unique(np.asarray(entry.data["timestamp"], dtype=float))


def _align(stamps: np.ndarray, values: np.ndarray, grid: np.ndarray, method: str) -> np.ndarray:
    if method == "held":
        return values[np.clip(np.searchsorted(stamps, grid, side="right") - 1, 0, values.size - 1)]
    return np.interp(grid, stamps, values)


def _record(source: str, stamps: np.ndarray, grid: np.ndarray, method: str) -> AlignedColumn:
    inside = stamps[(stamps >= grid[0]) & (stamps <= grid[-1])]
    around = stamps[max(np.searchsorted(stamps, grid[0]) - 1, 0):np.searchsorted(stamps, grid[-1]) + 1]
    span = (grid[-1] - grid[0]) * 1e-6
    gap = float(np.max(np.diff(around))) * 1e-6 if around.size > 1 else span
    return AlignedColumn(source, method, float(inside.size / span) if span > 0 else 0.0, gap)
