"""The checks every entry point runs on what a user passes: numbers, arrays, covariances, and
folders a campaign may write into.

One layer for all of them (the estimator, the filters and smoothers, the recursive
estimators, the delays, the readers, result files and campaigns), so that the same mistake
gets the same message wherever it is made: each failure is a :class:`casest.CasestError`
naming the argument, what was wrong with it, and the fix.
"""

from __future__ import annotations

import difflib
import math
import os
from typing import Sequence

import numpy as np

from .errors import CasestError, DataError, OptionError

__all__ = [
    "noise_covariance",
    "LARGEST_MAGNITUDE",
    "SMALLEST_RMS",
    "positive_number",
    "whole_number",
    "finite_array",
    "check_magnitude",
    "matrix_argument",
    "covariance_argument",
    "information_argument",
    "noise_variances",
    "own_folder",
    "with_suggestion",
]

#: largest magnitude whose square (sums of squares, Gram matrices, P = Phi P Phi' + Q) stays far
#: from overflow, and the smallest non-zero RMS whose square stays far from underflow
LARGEST_MAGNITUDE, SMALLEST_RMS = 1e150, 1e-150


def positive_number(value, name: str, unit: str = "seconds", error: type[CasestError] = OptionError,
                    meaning: str = "") -> float:
    """``value`` as a finite positive float.

    Parameters
    ----------
    value : object
        What the user gave.
    name : str
        The argument's name, as the user wrote it (``"sample_time"``, ``"dt"``).
    unit : str
        Its unit, named in the message.
    error : type
        The :class:`casest.CasestError` subclass raised.
    meaning : str
        What the number is (``"the record's sampling interval"``), for the message.

    Returns
    -------
    float

    Raises
    ------
    CasestError
        ``value`` is not a number, or is NaN, infinite, zero or negative.
    """
    what = f"{name} must be {meaning + ', ' if meaning else ''}a positive number of {unit}"
    if isinstance(value, bool):
        raise error(f"{what}; got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise error(f"{what}; got {value!r} ({type(value).__name__})") from None
    if not (math.isfinite(number) and number > 0):
        raise error(f"{what}; got {value!r}")
    return number


def whole_number(value, requirement: str, minimum: int = 1, error: type[CasestError] = OptionError) -> int:
    """``value`` as a Python int of at least ``minimum`` (a bool, a float or text is not one).

    Parameters
    ----------
    value : object
        What the user gave.
    requirement : str
        The message's words, naming the argument and what it counts
        (``"steps must be a whole number of samples >= 1"``); ``", got <value>"`` is appended.
    minimum : int
    error : type
        The :class:`casest.CasestError` subclass raised.

    Returns
    -------
    int

    Raises
    ------
    CasestError
        ``value`` is not an integer, or is below ``minimum``.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise error(f"{requirement}, got {value!r}")
    return int(value)


def finite_array(value, name: str, shape: tuple | None = None, error: type[CasestError] = DataError,
                 allow_nan: bool = False, min_rows: int = 0) -> np.ndarray:
    """``value`` as a float array whose entries are finite (NaN allowed where ``allow_nan``, marking
    a value not measured).

    Parameters
    ----------
    value : array_like
    name : str
        The argument's name, for the message.
    shape : tuple, optional
        Required shape; ``None`` in an entry accepts any length there.
    error : type
        The :class:`casest.CasestError` subclass raised.
    allow_nan : bool
        Accept NaN (never infinity).
    min_rows : int
        Least length of the first axis.

    Returns
    -------
    ndarray

    Raises
    ------
    CasestError
        Not numbers, the wrong shape, too few rows, or entries that are not finite (the first
        rows named).
    """
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise error(f"{name} must be an array of numbers, got {type(value).__name__}") from None
    if shape is not None and (arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape))):
        wanted = "(" + ", ".join("any" if s is None else str(s) for s in shape) + ")"
        raise error(f"{name} must have shape {wanted}, got {arr.shape}")
    if arr.ndim and arr.shape[0] < min_rows:
        raise error(f"{name} needs at least {min_rows} rows (samples), got {arr.shape[0]}")
    bad = np.isinf(arr) if allow_nan else ~np.isfinite(arr)
    if bad.any():
        rows = np.flatnonzero(bad.reshape(arr.shape[0], -1).any(axis=1))[:5].tolist() if arr.ndim else []
        kind = "infinite values" if allow_nan else "NaN or infinite values"
        fix = "; NaN marks a value not measured" if allow_nan else "; fill or drop those samples"
        raise error(f"{name} holds {kind}" + (f" at rows {rows}" if rows else "") + fix)
    return arr


def check_magnitude(name: str, arr: np.ndarray, error: type[CasestError] = DataError) -> None:
    """Refuse values whose squares overflow or underflow double precision.

    Parameters
    ----------
    name : str
        The column or argument, for the message.
    arr : ndarray
        Finite values.
    error : type
        The :class:`casest.CasestError` subclass raised.

    Raises
    ------
    CasestError
        A magnitude above :data:`LARGEST_MAGNITUDE` or a non-zero RMS below :data:`SMALLEST_RMS`,
        with the change of unit that fixes it.
    """
    peak = float(np.max(np.abs(arr))) if arr.size else 0.0
    if peak > LARGEST_MAGNITUDE:
        raise error(
            f"column {name!r} reaches {peak:.3g}: its squares overflow double precision (max 1.8e308), which "
            f"the least squares and the likelihood need; express it in a larger unit (divide it by about "
            f"{10 ** round(np.log10(peak)):.0e})"
        )
    rms = float(np.sqrt(np.mean(arr**2))) if arr.size and peak < 1e100 else 0.0
    if 0.0 < rms < SMALLEST_RMS:
        raise error(
            f"column {name!r} has an RMS of {rms:.3g}: its squares underflow double precision; express it in "
            f"a smaller unit (multiply it by about {10 ** -round(np.log10(rms)):.0e})"
        )


def matrix_argument(value, shape: tuple, name: str) -> np.ndarray:
    """``value`` as a finite float array of ``shape`` (a vector of n values stands for an (n, n) diagonal).

    Parameters
    ----------
    value : array_like
    shape : tuple
    name : str
        The argument's name, for the message.

    Returns
    -------
    ndarray, shape ``shape``

    Raises
    ------
    OptionError
        The wrong shape, or entries that are not finite.
    """
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 1 and len(shape) == 2 and shape[0] == shape[1] and arr.size == shape[0]:
        arr = np.diag(arr)  # a vector of variances
    if arr.shape != shape:
        raise OptionError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise OptionError(f"{name} has non-finite entries")
    return arr


def covariance_argument(value, n: int, name: str) -> np.ndarray:
    """``value`` as a symmetric positive semi-definite (n, n) covariance (symmetrised).

    Parameters
    ----------
    value : array_like, shape (n, n) or (n,)
        A covariance, or its diagonal.
    n : int
    name : str
        The argument's name, for the message.

    Returns
    -------
    ndarray, shape (n, n)

    Raises
    ------
    OptionError
        Not finite, not symmetric, not positive semi-definite, or so large that the filters'
        products of it overflow.
    """
    arr = matrix_argument(value, (n, n), name)
    peak = float(np.abs(arr).max()) if arr.size else 0.0
    if peak > LARGEST_MAGNITUDE:
        raise OptionError(f"{name} reaches {peak:.3g}: the filter's products of it overflow double precision (max "
                          f"1.8e308); express the states or outputs in larger units, or give a realistic variance")
    if not np.allclose(arr, arr.T, rtol=1e-10, atol=1e-14 * max(1.0, peak)):
        raise OptionError(f"{name} must be symmetric")
    if arr.size and np.linalg.eigvalsh(0.5 * (arr + arr.T))[0] < -1e-12 * max(1.0, peak):
        raise OptionError(f"{name} must be positive semi-definite (a variance cannot be negative)")
    return 0.5 * (arr + arr.T)


def noise_variances(value, outputs, name: str = "R") -> np.ndarray:
    """Measurement-noise variances, one per output, each positive and finite: the one check of a
    diagonal R that every estimator shares.

    Parameters
    ----------
    value : array_like, shape (n_outputs,)
    outputs : sequence of str
        The outputs, in order (for the message).
    name : str
        The argument's name, for the message.

    Returns
    -------
    ndarray, shape (n_outputs,)
        Output unit squared.

    Raises
    ------
    OptionError
        Another number of values, a value that is not a positive finite number.
    """
    outputs = list(outputs)
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise OptionError(f"{name} must hold {len(outputs)} noise variances {outputs}, got {value!r}") from None
    if arr.size != len(outputs) or not np.all(np.isfinite(arr) & (arr > 0)):
        raise OptionError(f"{name} must hold {len(outputs)} positive finite noise variances {outputs} (output unit "
                          f"squared), got {arr.tolist()}")
    return arr


def noise_covariance(value, outputs, name: str = "R") -> np.ndarray:
    """A full measurement-noise covariance: finite, n_outputs x n_outputs and positive definite
    (the one check of a full R that every estimator shares; :func:`noise_variances` checks a
    diagonal one).

    Parameters
    ----------
    value : array_like, shape (n_outputs, n_outputs)
    outputs : sequence of str
        The outputs, in order (for the message).
    name : str
        The argument's name, for the message.

    Returns
    -------
    ndarray, shape (n_outputs, n_outputs)
        Symmetrised; output units squared.

    Raises
    ------
    OptionError
        Another shape, a value that is not finite, a matrix that is not positive definite.
    """
    n = len(list(outputs))
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise OptionError(f"{name} must be a positive definite {n} x {n} covariance, got {value!r}") from None
    if arr.shape != (n, n) or not np.all(np.isfinite(arr)) or np.linalg.eigvalsh(0.5 * (arr + arr.T))[0] <= 0:
        raise OptionError(f"{name} must be a positive definite {n} x {n} covariance of the outputs {list(outputs)}, "
                          f"got {arr.tolist()}")
    return 0.5 * (arr + arr.T)


def information_argument(value, n: int, name: str = "information0", default: float = 1e-6) -> np.ndarray:
    """A recursive estimator's starting information: an (n, n) matrix, its diagonal, or a weak default.

    Parameters
    ----------
    value : array_like, shape (n,) or (n, n), or None
        None: ``default`` on the diagonal (almost no prior information).
    n : int
    name : str
        The argument's name, for the message.
    default : float

    Returns
    -------
    ndarray, shape (n, n)

    Raises
    ------
    OptionError
        Another shape, a value that is not finite, a matrix that is not symmetric positive definite.
    """
    info = np.full(n, default) if value is None else np.asarray(value, dtype=float)
    info = np.diag(info) if info.ndim == 1 else info.copy()
    if info.shape != (n, n):
        raise OptionError(f"{name} must be ({n},) or ({n}, {n})")
    if not np.all(np.isfinite(info)) or not np.allclose(info, info.T, rtol=1e-10, atol=0.0):
        raise OptionError(f"{name} must be finite and symmetric")
    if np.linalg.eigvalsh(0.5 * (info + info.T))[0] <= 0:
        raise OptionError(f"{name} must be positive definite (an information of zero says nothing is known: give a "
                          f"small positive one, e.g. {default:g} on the diagonal, or leave it out)")
    return info


def own_folder(path: str | os.PathLike, mark: str, error: type[CasestError], ignored: Sequence[str] = (),
               kind: str = "campaign", ignored_prefixes: Sequence[str] = ()) -> str:
    """A folder casest may write into: new, empty, or one casest wrote (it holds ``mark``);
    created when missing. A user's own files of the same names are never replaced.

    Parameters
    ----------
    path : str or path-like
    mark : str
        The file that shows casest wrote the folder (a campaign's ``config.json``).
    error : type
        The :class:`casest.CasestError` subclass raised.
    ignored : sequence of str
        Names that do not make a folder foreign (a lock file).
    kind : str
        What writes there, for the message.
    ignored_prefixes : sequence of str
        Name prefixes that do not make a folder foreign (temporary copies of atomic writes).

    Returns
    -------
    str
        The folder's path.

    Raises
    ------
    CasestError
        ``path`` is a file, or a folder holding files without ``mark`` (the first five named).
    """
    path = os.fspath(path)
    if os.path.exists(path) and not os.path.isdir(path):
        raise error(f"{path!r} is a file; the {kind} output must be a folder")
    if os.path.isdir(path) and not os.path.exists(os.path.join(path, mark)):
        foreign = sorted(name for name in os.listdir(path) if name not in set(ignored)
                         and not name.startswith(tuple(ignored_prefixes)))
        if foreign:
            shown = ", ".join(foreign[:5]) + (" ..." if len(foreign) > 5 else "")
            raise error(f"{path!r} already holds files that no casest {kind} wrote ({shown}); the {kind} would "
                        "overwrite some of them: give a new or empty folder")
    os.makedirs(path, exist_ok=True)
    return path


def flag_argument(value, name: str, allow_none: bool = False) -> bool | None:
    """A True/False option, checked: ``"yes"`` or ``1`` is refused rather than read by its truth.

    Parameters
    ----------
    value : object
    name : str
        The option's name, for the message.
    allow_none : bool
        None is a value of its own (the default's choice).

    Returns
    -------
    bool or None

    Raises
    ------
    OptionError
        Not True or False (or None where allowed).
    """
    if value is None and allow_none:
        return None
    if not isinstance(value, (bool, np.bool_)):
        allowed = "True, False or None" if allow_none else "True or False"
        raise OptionError(f"{name} must be {allowed}, got {value!r}")
    return bool(value)


def with_suggestion(name, candidates: Sequence[str], template: str = "did you mean {}?") -> str:
    """``name`` quoted, with the closest of ``candidates`` when one is close, for a message.

    Parameters
    ----------
    name : object
        The unknown or missing name.
    candidates : sequence of str
        The names it may have meant.
    template : str
        The suggestion's words, ``{}`` standing for the close candidate (quoted).

    Returns
    -------
    str
        ``"'nme' (did you mean 'name'?)"``, or ``"'nme'"`` when nothing is close.
    """
    close = difflib.get_close_matches(str(name), [str(c) for c in candidates], n=1)
    if not close:
        return repr(name)
    return f"{name!r} ({template.format(repr(close[0]))})"
