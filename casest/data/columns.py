"""Checks of a data set's columns: names, shapes, finite values and magnitudes that double
precision can square (:class:`casest.Dataset` runs them on construction)."""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from ..checks import check_magnitude
from ..checks import with_suggestion
from ..errors import DataError


__all__ = ["check_column_names", "column_array", "check_values", "check_magnitude"]

def check_column_names(model, columns: Mapping, needed: list, extra: Sequence[str]) -> None:
    """Refuse unknown columns (with a "did you mean") and missing ones (with the closest column)."""
    known = set(needed) | set(extra)
    unknown = [name for name in columns if name not in known]
    if unknown:
        raise DataError(
            f"unknown column(s) {', '.join(with_suggestion(n, needed) for n in unknown)}: model {model.name!r} has signals "
            f"{list(model.signal_names)} and outputs {list(model.output_names)}; "
            "rename the column or pass it in `extra`"
        )
    missing = [name for name in needed if name not in columns]
    if missing:
        hints = ", ".join(with_suggestion(n, list(columns), "closest column: {}") for n in missing)
        raise DataError(f"missing column(s) for model {model.name!r}: {hints}")


def column_array(name: str, values, earlier: dict, needed: list) -> np.ndarray:
    """One column as a 1-D float array of the same length as the columns before it."""
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(f"column {name!r} is not numeric: {exc}") from None
    if arr.ndim == 2 and 1 in arr.shape:
        arr = arr.reshape(-1)
    if arr.ndim != 1:
        raise DataError(f"column {name!r} must be 1-D of length N, got shape {arr.shape}")
    if earlier:
        length = next(iter(earlier.values())).size
        if arr.size != length:
            raise DataError(
                f"column {name!r} has {arr.size} samples but {needed[0]!r} has {length}; "
                "all columns must have the same length"
            )
    return arr


def check_values(name: str, arr: np.ndarray, model, allow_missing: bool) -> None:
    """Refuse NaN (unless a missing output is allowed), infinite and overflowing values, naming the rows."""
    is_output = name in model.output_names
    bad = np.flatnonzero(np.isinf(arr) if allow_missing and is_output else ~np.isfinite(arr))  # NaN: not measured
    if bad.size:
        rows = ", ".join(str(r) for r in bad[:5]) + (" ..." if bad.size > 5 else "")
        raise DataError(
            f"column {name!r} has {bad.size} NaN or infinite value(s) at row(s) "
            f"{rows} (0-based); drop or fill those samples before estimating"
            + (", or allow missing outputs if it was not measured there (missing='allow'; on the "
               "command line --allow-missing)" if is_output else "")
        )
    check_magnitude(name, arr[np.isfinite(arr)])
