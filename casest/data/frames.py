"""pandas data frames in and out: a record's columns from a frame (names, units, a time index),
and tables of results as frames. pandas is an optional extra (``pip install 'casest[frames]'``)."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..errors import DataError, MissingExtraError
from .csv_text import parse_header, refuse_duplicate_names
from .units import convert_to_model_units


__all__ = ["frame_columns", "require_pandas"]


def require_pandas():
    """The pandas module, or a :class:`casest.errors.MissingExtraError` naming the extra.

    Returns
    -------
    module
    """
    try:
        import pandas
    except ImportError as exc:
        raise MissingExtraError("data frames need pandas, which is not installed: pip install 'casest[frames]'") from exc
    return pandas


def frame_columns(model, frame, units: Mapping[str, str] | None = None, where: str = "the data frame") -> tuple:
    """The columns of ``frame`` as float arrays in the model's units, and the undeclared units.

    Column labels are names, optionally followed by a unit in brackets (``"V_N [m/s]"``, as a
    CSV header); a pint-pandas column (dtype ``pint[...]``) brings its own unit; ``units`` gives
    (or overrides) a column's unit by its name. A column in
    another unit than the model declares is converted (pint) or refused. When the model has a
    time signal that no column carries, the index is the time: a datetime or timedelta index
    in seconds from its first sample, a numeric index as it is.

    Parameters
    ----------
    model : Model or DynamicModel
    frame : pandas.DataFrame
    units : mapping of str to str, optional
        Column name -> unit.
    where : str
        How messages name the frame.

    Returns
    -------
    columns : dict of str to ndarray
    undeclared : dict of str to str
        Columns whose unit the model does not declare (used as they are).

    Raises
    ------
    DataError
        Not a data frame, duplicated or unparsable labels, a column that is not numeric, a
        unit that cannot be converted, a time index that is not increasing.
    """
    pandas = require_pandas()
    if not isinstance(frame, pandas.DataFrame):
        raise DataError(f"{where}: expected a pandas.DataFrame, got {type(frame).__name__}")
    parsed = [parse_header(str(label), where) for label in frame.columns]
    names = [name for name, _ in parsed]
    refuse_duplicate_names(names, where)
    column_units = {name: unit for name, unit in parsed if unit}
    columns = {}
    for (name, _), label in zip(parsed, frame.columns):
        series = frame[label]
        quantity = getattr(series.dtype, "units", None)  # a pint-pandas column carries its unit
        if quantity is not None:
            column_units[name] = str(quantity)
            series = series.pint.magnitude  # its numbers in that unit (to_numpy would drop the unit)
        try:
            columns[name] = series.to_numpy(dtype=float, na_value=np.nan)
        except (TypeError, ValueError):
            raise DataError(f"{where}: column {name!r} is not numeric (dtype {frame[label].dtype})") from None
    unknown = sorted(set(dict(units or {})) - set(names))
    if unknown:
        raise DataError(f"{where}: units= names {unknown}, which the frame does not hold (columns: {sorted(names)})")
    column_units.update(dict(units or {}))
    time = getattr(model, "time", None)
    if time is not None and time not in columns:
        columns[time] = _index_seconds(frame.index, pandas, where)
    undeclared = convert_to_model_units(model, columns, {n: column_units.get(n, "") for n in columns}, where)
    return columns, undeclared


def _index_seconds(index, pandas, where: str) -> np.ndarray:
    """A frame's index as time in seconds (a datetime or timedelta index from its first sample, or
    a numeric index named for its unit); the default row numbering is not a time."""
    if isinstance(index, pandas.RangeIndex) and index.name is None:
        raise DataError(f"{where}: the model needs a time column and the frame has only row numbers "
                        "(a default RangeIndex): give a time column, or set the index to the time "
                        "(frame.set_index('t'), a datetime or timedelta index)")
    if isinstance(index, (pandas.DatetimeIndex, pandas.TimedeltaIndex)):
        seconds = np.asarray((index - index[0]) / pandas.Timedelta(seconds=1), dtype=float)
    else:
        try:
            seconds = np.asarray(index, dtype=float)
        except (TypeError, ValueError):
            raise DataError(f"{where}: the model needs a time column and the index is not a time "
                            f"({type(index).__name__}); give a time column or a datetime, timedelta or numeric index") from None
    bad = np.flatnonzero(~np.isfinite(seconds))
    if bad.size:
        raise DataError(f"{where}: the time index has missing stamps (NaT or NaN) at rows {bad[:5].tolist()}; drop "
                        "those rows or fill their time")
    steps = np.diff(seconds)
    repeated = np.flatnonzero(steps == 0)
    if repeated.size:
        raise DataError(f"{where}: the time index repeats stamps at rows {(repeated + 1)[:5].tolist()}; drop the "
                        "duplicates (frame[~frame.index.duplicated()])")
    if seconds.size > 1 and not np.all(steps > 0):
        raise DataError(f"{where}: the time index is not increasing; sort the frame by time")
    return seconds
