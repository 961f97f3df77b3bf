"""MATLAB ``.mat`` records (flight-test data are often kept as MAT files): the columns of a
:class:`~casest.data.dataset.Dataset` (``Dataset.from_mat``) read through SciPy.

A column is found by a *path* into the file: a variable (``"AoA"``), a field of a nested
struct (``"validationData.response.airspeed"``), optionally with indices that pick one row of
an array holding several channels (``"validationData.response.w[1]"``: the second row of a
3 x N field; ``"...R[2, 0]"``: one entry of a 3 x 3 x N field). The sample axis of an array is
its longest axis; the indices address the other axes in order, from 0.
"""

from __future__ import annotations

import difflib
import os
import re
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from ..checks import positive_number
from ..errors import DataError
from .files import readable_file
from .units import convert_to_model_units


__all__ = ["MatColumns", "read_mat_columns", "mat_columns_needed", "read_mat_paths"]

_PATH = re.compile(r"^\s*([A-Za-z_]\w*(?:\s*\.\s*[A-Za-z_]\w*)*)\s*(?:\[\s*(\d+(?:\s*,\s*\d+)*)\s*\])?\s*$")


class MatColumns(NamedTuple):
    """The columns read from a MAT file, in the model's units where it declares them."""

    arrays: dict
    undeclared_units: dict


def mat_columns_needed(model, extra: Sequence[str] = ()) -> list[str]:
    """The columns a record of ``model`` needs: its signals and outputs (less those the model
    derives itself, such as lagged inputs), the states started from the data, and ``extra``.

    Parameters
    ----------
    model : Model or DynamicModel
    extra : sequence of str
        Further columns to read (kept in :attr:`Dataset.extra`).

    Returns
    -------
    list of str
    """
    derived = getattr(model, "derived_columns", set)()
    names = [n for n in list(model.signal_names) + list(model.output_names) if n not in derived]
    names += [n for n in getattr(model, "initial_from_data", ()) if n not in names]
    return names + [n for n in extra if n not in names]


def read_mat_columns(model, path: str | os.PathLike, variables: Mapping | None = None,
                     units: Mapping[str, str] | None = None, extra: Sequence[str] = (),
                     sample_time: float | None = None) -> MatColumns:
    """Read the columns a record of ``model`` needs from a MATLAB ``.mat`` file (v4 to v7; SciPy).

    Parameters
    ----------
    model : Model or DynamicModel
        Its signal names (a dynamic model's first signal is the time), output names and the
        states whose initial value comes from the data are the columns read.
    path : str or path-like
    variables : mapping, optional
        Where each column is in the file: a path (``{"alpha": "AoA"}``,
        ``{"q": "flight.response.w[1]"}``: module docstring) or ``(variable, k)`` for column
        k, from 0, of an N x m matrix variable. A column not listed is the variable of its
        own name.
    units : mapping of str to str, optional
        The unit each column has in the file (``{"alpha": "deg"}``); it is converted to the
        unit the model declares (pint, ``pip install 'casest[units]'``), as for a CSV header.
    extra : sequence of str
        Further columns to read besides the model's (for example a column to split the
        record by, or a reference signal for plots).
    sample_time : float, optional
        A dynamic model's time column as ``k * sample_time`` (s), k = 0 ... N-1, for files
        that hold no time; refused when the time column is also mapped.

    Returns
    -------
    MatColumns
        ``arrays``: each column, shape (N,); ``undeclared_units``: columns whose given unit
        the model does not declare (name: unit), used as they are.

    Raises
    ------
    DataError
        A missing file, a file that is not a MAT file (or is v7.3, HDF5), a path that is not
        there (with the names that are), not numeric, or of the wrong shape; ``variables`` or
        ``units`` naming a column that is not read.
    """
    path = os.fspath(path)
    stored = _load(path)
    variables = dict(variables or {})
    names = mat_columns_needed(model, extra)
    for option, given in (("variables", variables), ("units", dict(units or {}))):
        unknown = sorted(set(given) - set(names))
        if unknown:
            raise DataError(f"{option}= names {unknown}, which are not signals or outputs of the model "
                            f"({names}); to keep other columns, list them in extra=")
    time = getattr(model, "time", None) if sample_time is not None else None
    if sample_time is not None:
        _check_sample_time(sample_time, time, variables)
    arrays = {name: _column(stored, name, variables.get(name, name), path) for name in names if name != time}
    if time is not None:
        n = next(iter(arrays.values())).size if arrays else 0
        arrays[time] = np.arange(n) * float(sample_time)
    undeclared = convert_to_model_units(model, arrays, dict(units or {}), path)
    return MatColumns(arrays, undeclared)


def read_mat_paths(path: str | os.PathLike, paths: Mapping[str, object]) -> dict:
    """Arrays read from a MATLAB ``.mat`` file by path, without a model (for example the measured
    arrays that :func:`casest.flight_path_columns` takes).

    Parameters
    ----------
    path : str or path-like
    paths : mapping of str to str or (str, int)
        Name -> a path (``"flight.response.w[1]"``, module docstring) or ``(variable, k)``.

    Returns
    -------
    dict of str to ndarray, shape (N,) each

    Raises
    ------
    DataError
        As :func:`read_mat_columns`.
    """
    path = os.fspath(path)
    stored = _load(path)
    return {name: _column(stored, name, where, path) for name, where in paths.items()}


def _check_sample_time(sample_time, time, variables) -> None:
    positive_number(sample_time, "sample_time", error=DataError, meaning="the record's sampling interval")
    if time is None:
        raise DataError("sample_time builds a dynamic model's time column; this model has no time column")
    if time in variables:
        raise DataError(f"the time column {time!r} is mapped in variables= and built from sample_time=; give one")


def _load(path: str) -> dict:
    """The file's variables (SciPy's ``loadmat``), with the errors a user can act on."""
    from scipy.io import loadmat
    from scipy.io.matlab import MatReadError

    if os.path.isdir(path):
        raise DataError(f"{path!r} is a folder, not a MAT file; give the path of the .mat file inside it")
    readable_file(path, "MAT file", DataError)
    try:
        content = loadmat(path)
    except NotImplementedError:  # SciPy's word for a v7.3 (HDF5) file
        raise DataError(f"{path}: a MATLAB v7.3 (HDF5) file; save it with save(..., '-v7') in MATLAB, or read it "
                        "with h5py and build the Dataset from arrays") from None
    except (MatReadError, ValueError, TypeError, OSError) as err:
        raise DataError(f"{path}: not a readable MATLAB .mat file ({err})") from None
    return {k: v for k, v in content.items() if not k.startswith("__")}


def _column(stored: dict, name: str, where, path: str) -> np.ndarray:
    """One column: a path (variable, struct fields, indices), or a column of a matrix variable."""
    if isinstance(where, str):
        match = _PATH.match(where)
        if not match:
            raise DataError(f"{path}: {where!r} (column {name!r}) is not a path; write 'variable', "
                            "'struct.field.subfield' or 'struct.field[k]' (k from 0)")
        parts = [p.strip() for p in match.group(1).split(".")]
        indices = tuple(int(i) for i in match.group(2).split(",")) if match.group(2) else None
        value = _resolve(stored, parts, name, path)
        return _pick(value, indices, ".".join(parts), name, path)
    variable, index = tuple(where)
    value = _numeric(_resolve(stored, [variable], name, path), variable, name, path)
    if value.ndim != 2 or not 0 <= int(index) < value.shape[1]:
        raise DataError(f"{path}: column {index} of variable {variable!r} (shape {value.shape}) does not exist "
                        f"(column {name!r}); columns are numbered from 0")
    return value[:, int(index)].copy()


def _resolve(stored: dict, parts: list, name: str, path: str):
    """The value at ``parts`` (a variable, then struct fields), with close names on a miss."""
    value, seen = stored, []
    for part in parts:
        fields = _fields(value)
        if fields is None:
            raise DataError(f"{path}: {'.'.join(seen)!r} is not a struct, so it has no field {part!r} (column "
                            f"{name!r})")
        if part not in fields:
            close = difflib.get_close_matches(part, fields, n=3)
            hint = f" (did you mean {' or '.join(map(repr, close))}?)" if close else ""
            where = f"field {part!r} in {'.'.join(seen)!r}" if seen else f"variable {part!r}"
            holds = f"the struct has fields {sorted(fields)}" if seen else f"the file holds {sorted(fields)}"
            raise DataError(f"{path}: no {where} for column {name!r}{hint}; {holds}; map it with variables={{"
                            f"{name!r}: 'VARIABLE'}}, {{{name!r}: 'STRUCT.FIELD[k]'}} or {{{name!r}: ('MATRIX', k)}}")
        value = value[part] if isinstance(value, dict) else _field(value, part, seen, path)
        seen.append(part)
    return value


def _fields(value) -> list | None:
    if isinstance(value, dict):
        return list(value)
    if isinstance(value, np.ndarray) and value.dtype.names:
        return list(value.dtype.names)
    return None


def _field(struct: np.ndarray, field: str, seen: list, path: str):
    if struct.size != 1:
        raise DataError(f"{path}: {'.'.join(seen)!r} is an array of {struct.size} structs; casest reads fields of "
                        "a single struct (index the struct array in MATLAB, or read it with scipy.io.loadmat)")
    return struct[field].reshape(-1)[0]


def _numeric(value, where: str, name: str, path: str) -> np.ndarray:
    if (not isinstance(value, np.ndarray) or value.dtype.names or not np.issubdtype(value.dtype, np.number)
            or np.iscomplexobj(value)):
        raise DataError(f"{path}: variable {where!r} (column {name!r}) is not a real numeric array")
    return np.asarray(value, dtype=float)


def _pick(value, indices, where: str, name: str, path: str) -> np.ndarray:
    """A vector, or the channel ``indices`` of an array whose longest axis is the sample axis."""
    value = _numeric(value, where, name, path)
    shape = value.shape
    if indices is None:
        if value.ndim == 2 and 1 in shape or value.ndim == 1:
            return value.reshape(-1)
        raise DataError(f"{path}: variable {where!r} (column {name!r}) has shape {shape}, not a vector; pick a column "
                        f"with variables={{{name!r}: ({where!r}, k)}} or a channel with {{{name!r}: '{where}[k]'}} (k "
                        "from 0 along the shorter axes)")
    samples = [ax for ax, n in enumerate(shape) if n == max(shape)]
    channel_axes = [ax for ax in range(value.ndim) if ax != samples[0]]
    if len(samples) > 1 and max(shape) > 1:
        raise DataError(f"{path}: {where!r} (column {name!r}) has shape {shape}: no single longest axis to take as "
                        "the samples; store the record with the samples along one axis")
    if len(indices) != len(channel_axes) or any(not 0 <= i < shape[ax] for i, ax in zip(indices, channel_axes)):
        sizes = " x ".join(str(shape[ax]) for ax in channel_axes) or "none"
        raise DataError(f"{path}: {where}{list(indices)} (column {name!r}) does not exist: {where!r} has shape "
                        f"{shape}, samples along axis {samples[0]}, channels {sizes} (indices from 0)")
    picker = [slice(None)] * value.ndim
    for i, ax in zip(indices, channel_axes):
        picker[ax] = i
    return np.ascontiguousarray(value[tuple(picker)])
