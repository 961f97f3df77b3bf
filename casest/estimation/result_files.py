"""How casest's results are written and read back: JSON text with lossless arrays and
non-finite numbers, atomic writes, the field decoders of ``from_dict``, and the checks that
refuse a damaged or edited estimate file."""

from __future__ import annotations

import json
import math
import os

import numpy as np

from ..data.dataset import atomic_write_text
from ..data.files import readable_file
from .html_report import write_html
from ..errors import ResultFileError


__all__ = ["JsonResult", "json_number", "number_of_json", "optional_decoder", "check_loaded_estimate",
           "load_json_result", "json_text", "DIGEST_FIELD"]

#: the field of a result file that holds the SHA-256 of the rest of its content (canonical JSON)
DIGEST_FIELD = "content_sha256"


def _content_digest(data: dict) -> str:
    """The SHA-256 of a result's plain form without its digest field, as canonical JSON (hex)."""
    import hashlib

    body = {k: v for k, v in data.items() if k != DIGEST_FIELD}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode("utf-8")).hexdigest()


def json_text(data: dict) -> str:
    """A result's file text: its plain form with :data:`DIGEST_FIELD` added, so that an edit made
    after casest wrote it is found when it is read back.

    Parameters
    ----------
    data : dict
        The result's plain-Python form (``to_dict``).

    Returns
    -------
    str
    """
    return json.dumps({**data, DIGEST_FIELD: _content_digest(data)}, indent=1)


def json_number(x):
    """A float for JSON: NaN and infinities as the strings ``"nan"``, ``"inf"``, ``"-inf"``.

    Parameters
    ----------
    x : float or None

    Returns
    -------
    float, str or None
    """
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else ("nan" if math.isnan(x) else ("inf" if x > 0 else "-inf"))


def number_of_json(x):
    """Inverse of :func:`json_number`.

    Parameters
    ----------
    x : float, str or None

    Returns
    -------
    float or None
    """
    return float(x) if isinstance(x, str) else x


def _same(value):
    """A field read back as it is."""
    return value


def optional_decoder(decode):
    """``decode`` for a field that may be None.

    Parameters
    ----------
    decode : callable

    Returns
    -------
    callable
        None for None, else ``decode(value)``.
    """
    return lambda value: None if value is None else decode(value)


class JsonResult:
    """``to_json`` / ``from_json`` of casest's results, on top of their ``to_dict`` / ``from_dict``.

    A result class names in ``FIELD_DECODERS`` how ``from_dict`` reads each saved field back
    (the others are taken as they are).
    """

    FIELD_DECODERS: dict = {}

    @classmethod
    def decoded_fields(cls, data: dict) -> dict:
        """The saved fields read back by ``FIELD_DECODERS`` (``format`` and ``note_codes`` left out).

        Parameters
        ----------
        data : dict
            The result's plain-Python form.

        Returns
        -------
        dict
        """
        return {k: cls.FIELD_DECODERS.get(k, _same)(v) for k, v in data.items() if k not in ("format", "note_codes")}

    def to_html(self, path: str | os.PathLike | None = None, title: str | None = None, model=None,
                data=None) -> str:
        """One self-contained HTML page of the result (:func:`casest.estimation.html_report.result_html`):
        conclusion, parameters, noise, notes, residual checks, the figures it can draw; written
        atomically to ``path`` when given.

        Parameters
        ----------
        path : str or os.PathLike, optional
        title : str, optional
        model : Model or DynamicModel, optional
            The model whose parameters the result lists, in its order.
        data : Dataset, or sequence / mapping of Dataset, optional
            With ``model``: the page adds the fit and the residuals in time on these records.

        Returns
        -------
        str
        """
        return write_html(self, path, title, model=model, data=data)

    def to_json(self, path: str | os.PathLike | None = None, *, landscape: bool = True) -> str:
        """JSON text; written atomically to ``path`` when given.

        Parameters
        ----------
        path : str or os.PathLike, optional
        landscape : bool
            Keep the stage-1 landscape (every candidate, its xi1 and R: most of the file); with
            False the file holds the estimate alone and loads with ``landscape`` None.

        Returns
        -------
        str
            The JSON text (lossless: :meth:`from_json` gives the same result back; arrays of
            more than 64 values as base64 of their bytes).
        """
        data = self.to_dict()
        if not landscape and "landscape" in data:
            data["landscape"] = None
        text = json_text(data)
        if path is not None:
            atomic_write_text(path, text + "\n")
        return text

    @classmethod
    def from_json(cls, path_or_text: str | os.PathLike):
        """Load from a JSON file path or JSON text.

        Parameters
        ----------
        path_or_text : str or os.PathLike

        Returns
        -------
        Estimate or FilterErrorEstimate
            The result of the class it is called on.

        Raises
        ------
        ResultFileError
            The file is missing, a folder, truncated, not JSON, or not a casest result of
            this kind (the message names the file and what is wrong).
        """
        return load_json_result(cls, path_or_text)


def load_json_result(cls, path_or_text: str | os.PathLike):
    """A result of class ``cls`` from a JSON file path or JSON text (through ``cls.from_dict``), every
    failure a :class:`ResultFileError` naming the file and what is wrong.

    Parameters
    ----------
    cls : type
        A result class with ``from_dict``.
    path_or_text : str or os.PathLike

    Returns
    -------
    object
        The result.
    """
    text = os.fspath(path_or_text)
    source = "the JSON text"
    if not text.lstrip().startswith("{"):
        source = repr(text)
        if os.path.isdir(text):
            raise ResultFileError(f"{source} is a folder, not an estimate file")
        if os.path.exists(text):  # a device, FIFO or socket could feed or block forever
            readable_file(text, "estimate file", ResultFileError)
        try:
            with open(text, encoding="utf-8") as fh:
                text = fh.read()
        except FileNotFoundError:
            raise ResultFileError(f"estimate file {source} does not exist") from None
        except UnicodeDecodeError:
            raise ResultFileError(f"{source} is not a text file, so not a casest estimate") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        what = "truncated (it ends before the JSON is complete)" if err.pos >= len(text.rstrip()) else "not valid JSON"
        raise ResultFileError(
            f"{source} is {what}: {err.msg} at line {err.lineno}, column {err.colno}; write it again with "
            f"{cls.__name__}.to_json"
        ) from None
    if not isinstance(data, dict):
        raise ResultFileError(f"{source} holds a JSON {type(data).__name__}, not a casest estimate")
    edited = DIGEST_FIELD in data and data[DIGEST_FIELD] != _content_digest(data)
    data = {k: v for k, v in data.items() if k != DIGEST_FIELD}
    try:
        result = cls.from_dict(data)  # a damaged or contradictory field is named first, by its own check
        if edited:  # consistent, but not what casest wrote (a value changed to another plausible one)
            raise ResultFileError(f"it was changed after casest wrote it (its content no longer matches the "
                                  f"{DIGEST_FIELD} casest recorded): an edited estimate would load as the original; "
                                  f"estimate again, or delete the {DIGEST_FIELD} field to load it as an unverified "
                                  "file")
        return result
    except ResultFileError as err:
        raise ResultFileError(f"{source}: {err}") from None
    except (KeyError, TypeError, ValueError) as err:
        raise ResultFileError(
            f"{source} is a casest estimate with a missing or malformed field ({type(err).__name__}: {err})"
        ) from None


#: the conclusion's words for data units the model does not declare (``NoteCode.UNITS``)


def check_loaded_estimate(est) -> None:
    """Refuse an estimate file whose numbers contradict each other or the model (an edited or
    damaged file would otherwise load and say "trust it").

    Parameters
    ----------
    est : Estimate

    Returns
    -------
    None

    Raises
    ------
    ResultFileError
        Fields of the wrong shape or type, theta not finite or outside its bounds, a negative or
        zero std, R not positive, a covariance or correlation no estimate has.
    """
    n, ny = len(est.parameter_names), len(est.output_names)
    shapes = {"theta": (n,), "std": (n,), "lower_bounds": (n,), "upper_bounds": (n,), "covariance": (n, n),
              "correlation": (n, n), "R": (ny,)}
    for field_name, shape in shapes.items():
        value = np.asarray(getattr(est, field_name))
        if value.shape != shape:
            raise ResultFileError(f"field {field_name!r} has shape {value.shape} but the estimate names {n} parameters "
                                  f"and {ny} outputs (expected {shape}); the file was cut or edited")
    for field_name in ("std_reasons", "active_bounds"):
        if len(getattr(est, field_name)) != n:
            raise ResultFileError(f"field {field_name!r} has {len(getattr(est, field_name))} entries for {n} parameters")
    _check_types(est)
    _check_values(est)
    _check_spread(est)


def _check_types(est) -> None:
    """Refuse fields of a type or range no estimate has: success not a boolean, counts not whole
    numbers (samples at least one, iterations at least zero)."""
    if not isinstance(est.success, (bool, np.bool_)):
        raise ResultFileError(f"field 'success' is {est.success!r}: it must be true or false")
    for field_name, low in (("n_samples", 1), ("n_iterations", 0)):
        value = getattr(est, field_name)
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ResultFileError(f"field {field_name!r} is {value!r}: it must be a whole number >= {low}")


def _check_spread(est) -> None:
    """Refuse a covariance or correlation no estimate has: a negative variance, a std of 0 where a
    std is given, a correlation outside [-1, 1], a covariance whose diagonal is not the std squared."""
    std = np.asarray(est.std, dtype=float)
    zero = [name for name, s, why in zip(est.parameter_names, std, est.std_reasons) if s == 0 and why is None]
    if zero:
        raise ResultFileError(f"the std of {zero} is 0, which no estimate from noisy data has; the file was edited")
    cov, corr = np.asarray(est.covariance, dtype=float), np.asarray(est.correlation, dtype=float)
    given = np.isfinite(std)
    diag = np.diag(cov)
    if np.any(diag[np.isfinite(diag)] < 0) or not np.allclose(diag[given], std[given] ** 2, rtol=1e-6, atol=0.0):
        raise ResultFileError("the covariance's diagonal is not the std squared (or is negative); the file was edited")
    if np.any(np.abs(corr[np.isfinite(corr)]) > 1 + 1e-9):
        raise ResultFileError(f"a correlation reaches {np.nanmax(np.abs(corr)):.3g}: correlations lie in [-1, 1]; the "
                              "file was edited")


def _check_values(est) -> None:
    """Refuse values no estimate has: theta not finite or outside its bounds, a negative std, R not positive."""
    bad = [name for name, v in zip(est.parameter_names, est.theta) if not np.isfinite(v)]
    if bad:
        raise ResultFileError(f"theta of {bad} is missing or not finite (null, NaN or infinite)")
    outside = _outside_bounds(est)
    if outside:
        raise ResultFileError(f"theta of {outside} lies outside its bounds, which no casest estimate does")
    negative = [name for name, v in zip(est.parameter_names, est.std) if np.isfinite(v) and v < 0]
    if negative:
        raise ResultFileError(f"the std of {negative} is negative")
    if not np.all(np.isfinite(est.R) & (np.asarray(est.R) > 0)):
        raise ResultFileError(f"the noise variances R {np.asarray(est.R).tolist()} must be positive and finite")


def _outside_bounds(est) -> list:
    """The parameters whose value lies outside their bounds by more than rounding (1e-9 of the span)."""
    with np.errstate(invalid="ignore"):  # inf - inf of unbounded parameters
        span = np.where(np.isfinite(est.upper_bounds - est.lower_bounds), est.upper_bounds - est.lower_bounds, 1.0)
    slack = 1e-9 * np.maximum(span, 1.0)
    return [name for name, v, lo, hi, e in zip(est.parameter_names, est.theta, est.lower_bounds, est.upper_bounds,
                                               slack) if v < lo - e or v > hi + e]
