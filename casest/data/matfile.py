"""MATLAB ``.mat`` records (flight-test data are often kept as MAT files): the columns of a
:class:`~casest.data.dataset.Dataset` (``Dataset.from_mat``) read through SciPy."""

from __future__ import annotations

import difflib
import os
from typing import Mapping, NamedTuple

import numpy as np

from ..errors import DataError
from .units import convert_to_model_units


__all__ = ["MatColumns", "read_mat_columns"]


class MatColumns(NamedTuple):
    """The columns read from a MAT file, in the model's units where it declares them."""

    arrays: dict
    undeclared_units: dict


def read_mat_columns(model, path: str | os.PathLike, variables: Mapping | None = None,
                     units: Mapping[str, str] | None = None) -> MatColumns:
    """Read the model's signals and outputs from a MATLAB ``.mat`` file (v4 to v7; SciPy).

    Parameters
    ----------
    model : Model or DynamicModel
        Its signal names (a dynamic model's first signal is the time) and output names are
        the columns read.
    path : str or path-like
    variables : mapping, optional
        Where each column is in the file: ``{"alpha": "AoA"}`` (a vector variable) or
        ``{"alpha": ("Z", 2)}`` (column 2, zero-based, of an N x m matrix ``Z``). A column
        not listed is the variable of its own name.
    units : mapping of str to str, optional
        The unit each column has in the file (``{"alpha": "deg"}``); it is converted to the
        unit the model declares (pint, ``pip install 'casest[units]'``), as for a CSV header.

    Returns
    -------
    MatColumns
        ``arrays``: each column, shape (N,); ``undeclared_units``: columns whose given unit
        the model does not declare (name: unit), used as they are.

    Raises
    ------
    DataError
        A missing file, a file that is not a MAT file (or is v7.3, HDF5), a variable that is
        not there (with the names that are), not numeric, or of the wrong shape.
    """
    from scipy.io import loadmat
    from scipy.io.matlab import MatReadError

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise DataError(f"MAT file {path!r} does not exist")
    try:
        content = loadmat(path)
    except NotImplementedError:  # SciPy's word for a v7.3 (HDF5) file
        raise DataError(f"{path}: a MATLAB v7.3 (HDF5) file; save it with save(..., '-v7') in MATLAB, or read it "
                        "with h5py and build the Dataset from arrays") from None
    except (MatReadError, ValueError, TypeError, OSError) as err:
        raise DataError(f"{path}: not a readable MATLAB .mat file ({err})") from None
    stored = {k: v for k, v in content.items() if not k.startswith("__")}
    variables = dict(variables or {})
    unknown = sorted(set(variables) - set(model.signal_names) - set(model.output_names))
    if unknown:
        raise DataError(f"variables= names {unknown}, which are not signals or outputs of the model "
                        f"({list(model.signal_names) + list(model.output_names)})")
    derived = getattr(model, "derived_columns", set)()  # lagged inputs: the Dataset derives them
    arrays = {name: _column(stored, name, variables.get(name, name), path)
              for name in list(model.signal_names) + list(model.output_names) if name not in derived}
    undeclared = convert_to_model_units(model, arrays, dict(units or {}), path)
    return MatColumns(arrays, undeclared)


def _column(stored: dict, name: str, where, path: str) -> np.ndarray:
    """One column: a vector variable, or a column of a matrix variable."""
    variable, index = (where, None) if isinstance(where, str) else tuple(where)
    if variable not in stored:
        close = difflib.get_close_matches(variable, list(stored), n=3)
        hint = f" (did you mean {' or '.join(map(repr, close))}?)" if close else ""
        raise DataError(f"{path}: no variable {variable!r} for column {name!r}{hint}; the file holds {sorted(stored)}; "
                        "map it with variables={" + repr(name) + ": 'VARIABLE'} or {" + repr(name) + ": ('MATRIX', k)}")
    value = stored[variable]
    if not isinstance(value, np.ndarray) or not np.issubdtype(value.dtype, np.number) or np.iscomplexobj(value):
        raise DataError(f"{path}: variable {variable!r} (column {name!r}) is not a real numeric array")
    value = np.asarray(value, dtype=float)
    if index is None:
        if value.ndim == 2 and 1 in value.shape:
            return value.reshape(-1)
        raise DataError(f"{path}: variable {variable!r} (column {name!r}) has shape {value.shape}, not a vector; "
                        f"pick a column with variables={{{name!r}: ({variable!r}, k)}}")
    if value.ndim != 2 or not 0 <= int(index) < value.shape[1]:
        raise DataError(f"{path}: column {index} of variable {variable!r} (shape {value.shape}) does not exist "
                        f"(column {name!r}); columns are numbered from 0")
    return value[:, int(index)].copy()
