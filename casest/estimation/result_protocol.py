"""What every casest estimate offers, whichever estimator made it: the result protocol.

:class:`EstimateLike` declares it: the parameters by name with their values, std and
covariance, whether the estimator stands behind the result (``success``, ``status``, coded
``notes``, the one-line ``conclusion``/``trust``), a text ``report``, a JSON file that loads back
and a pandas frame. The two-stage and output-error :class:`~casest.Estimate`, the filter-error
estimate, the frequency-domain estimate, regression (least squares and total least squares)
and stepwise regression implement it; :func:`parameters_frame` and the figures take any of
them. :class:`PlainResult` gives the protocol's file, frame and trust line to the frozen
dataclass results of the closed-form estimators.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Protocol, runtime_checkable

import numpy as np

from ..data.files import atomic_write_text
from ..errors import ResultFileError
from ..status import NoteCode, TrustCode, note_code
from .html_report import compact_html, write_html
from .result_files import json_text, load_json_result
from .result_schema import decode_field, encode_field, file_format, format_version, register_record
from .diagnosis import Diagnosis
from .diagnostics import ResidualCheck
from .verdict import ColouredStd, judged, residual_verdict

__all__ = ["EstimateLike", "PlainResult", "parameters_frame", "conclusion_of"]


@runtime_checkable
class EstimateLike(Protocol):
    """The result protocol (module docstring): every estimator's result has these.

    Attributes
    ----------
    parameter_names : tuple of str
    theta : ndarray, shape (n_parameters,)
        The estimates, in the parameters' units.
    std : ndarray, shape (n_parameters,)
        One standard deviation each (NaN where there is none; the notes say why).
    covariance : ndarray, shape (n_parameters, n_parameters) or larger
        The covariance the std come from (its leading block is the parameters').
    success : bool
        Whether the estimator stands behind the result.
    status : str
        How the solve ended.
    notes : sequence of Note
        Each a ``str`` with its :class:`~casest.status.NoteCode` in ``.code``.
    """

    parameter_names: tuple
    theta: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    success: bool
    status: str
    notes: list

    @property
    def values(self) -> dict:
        """Estimates by parameter name."""

    @property
    def stds(self) -> dict:
        """Standard deviations by name (None where there is none)."""

    def report(self) -> str:
        """The text report, closing with the conclusion line.

        Returns
        -------
        str
        """

    def to_json(self, path: str | os.PathLike | None = None) -> str:
        """JSON text, written atomically to ``path`` when given; ``from_json`` loads it back.

        Parameters
        ----------
        path : str or os.PathLike, optional

        Returns
        -------
        str
        """

    def to_dataframe(self):
        """The parameters as a pandas data frame (value and std by parameter name).

        Returns
        -------
        pandas.DataFrame
        """

    def conclusion(self) -> tuple:
        """What casest says of the result.

        Returns
        -------
        TrustCode
        str
            The reason, in words a user can act on.
        """

    def trust(self) -> tuple:
        """Whether to trust the result (the conclusion is ``TRUSTED``), and why (not).

        Returns
        -------
        bool
        str
        """


def parameters_frame(result: EstimateLike):
    """Any estimate's parameters as a pandas data frame (needs pandas).

    Parameters
    ----------
    result : EstimateLike

    Returns
    -------
    pandas.DataFrame
        One row per parameter (index ``parameter``): ``value``, ``std`` (NaN where there is none),
        and ``unit``, ``lower``, ``upper`` where the result knows them.
    """
    from ..data.frames import require_pandas

    pandas = require_pandas()
    names = list(result.parameter_names)
    columns = {"value": np.asarray(result.theta, dtype=float), "std": np.asarray(result.std, dtype=float)}
    units = getattr(result, "parameter_units", ())
    if units:
        columns["unit"] = list(units)
    for key, attribute in (("lower", "lower_bounds"), ("upper", "upper_bounds")):
        if getattr(result, attribute, None) is not None:
            columns[key] = np.asarray(getattr(result, attribute), dtype=float)
    return pandas.DataFrame(columns, index=pandas.Index(names, name="parameter"))


def conclusion_of(result: EstimateLike, solved: str, coloured: ColouredStd = ColouredStd(),
                  diagnosis=None) -> tuple[TrustCode, str]:
    """The trust line of a result without a global search: ``CAUTION`` naming what failed (no
    success, a parameter without std, a coded warning), else what its residual tests say
    (``residual_checks`` where it has them, :func:`casest.estimation.verdict.judged`), else
    ``LOCAL`` with ``solved`` saying what was done.

    Parameters
    ----------
    result : EstimateLike
    solved : str
        What the estimator did, for the reason (``"the closed-form least squares"``).
    coloured : ColouredStd
        The ratio of the colored-residual std the result reports to the white-noise std.
    diagnosis : Diagnosis, optional
        What explains residuals that depend on something.

    Returns
    -------
    TrustCode
    str
    """
    problems = []
    if not result.success:
        problems.append(f"the estimator did not succeed ({result.status})")
    missing = [n for n, s in zip(result.parameter_names, result.std) if not np.isfinite(s)]
    if missing:
        problems.append(f"no standard deviation for {missing} (see the notes)")
    warned = [n for n in result.notes if note_code(n) in (NoteCode.NOT_VERIFIED, NoteCode.NOT_IDENTIFIABLE,
                                                          NoteCode.FREQUENCIES, NoteCode.NOT_FINITE)]
    problems += [str(n) for n in warned]
    checks = tuple(getattr(result, "residual_checks", ()) or ())
    tested = f"; the residuals pass {len(checks)} test(s)" if checks else \
        "; the std assume the model and noise model are right"
    return judged(problems, residual_verdict(checks), (TrustCode.LOCAL, f"{solved}, every parameter has a std{tested}"),
                  coloured, diagnosis)


class PlainResult:
    """The protocol's file, frame and trust line for a frozen dataclass result: ``KIND`` names its
    kind of file (``"casest.Regression"``); the fields are written in the one schema of
    :mod:`casest.estimation.result_schema` (arrays exact, notes with their codes)."""

    KIND = ""

    @property
    def values(self) -> dict:
        """Estimates by parameter name."""
        return dict(zip(self.parameter_names, np.asarray(self.theta, dtype=float).tolist()))

    @property
    def stds(self) -> dict:
        """Standard deviations by name (None where there is none)."""
        return {n: (float(s) if np.isfinite(s) else None) for n, s in zip(self.parameter_names, self.std)}

    def to_html(self, path: str | os.PathLike | None = None, title: str | None = None, model=None,
                data=None) -> str:
        """One self-contained HTML page of the result (:func:`casest.estimation.html_report.result_html`),
        written atomically to ``path`` when given.

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

    def _repr_html_(self) -> str:
        """The notebook's view: the conclusion and the parameter table."""
        return compact_html(self)

    def to_dataframe(self):
        """The parameters as a pandas data frame (:func:`parameters_frame`).

        Returns
        -------
        pandas.DataFrame
        """
        return parameters_frame(self)

    def trust(self) -> tuple[bool, str]:
        """Whether to trust the result, and why (not): see :meth:`conclusion`.

        Returns
        -------
        bool
        str
        """
        code, reason = self.conclusion()
        return code is TrustCode.TRUSTED, reason

    def to_dict(self) -> dict:
        """Plain-Python form, every field by :func:`~casest.estimation.result_schema.encode_field`.

        Returns
        -------
        dict
        """
        return {"format": file_format(self.KIND),
                **{item.name: encode_field(getattr(self, item.name)) for item in dataclasses.fields(self)}}

    @classmethod
    def from_dict(cls, data: dict):
        """The result of :meth:`to_dict`'s form.

        Parameters
        ----------
        data : dict

        Returns
        -------
        PlainResult
        """
        if not isinstance(data, dict):
            raise ResultFileError(f"not a {cls.__name__} file (a JSON {type(data).__name__})")
        format_version(data.get("format"), cls.KIND, f"casest {cls.__name__}")  # version 1 is read alike
        try:
            kwargs = {item.name: decode_field(data[item.name]) for item in dataclasses.fields(cls) if item.name in data}
            return cls(**kwargs)
        except (KeyError, TypeError, ValueError) as err:
            raise ResultFileError(f"a {cls.__name__} file with a damaged field: {err}") from None

    def to_json(self, path: str | os.PathLike | None = None) -> str:
        """JSON text; written atomically to ``path`` when given.

        Parameters
        ----------
        path : str or os.PathLike, optional

        Returns
        -------
        str
        """
        text = json_text(self.to_dict())
        if path is not None:
            atomic_write_text(path, text + "\n")
        return text

    @classmethod
    def from_json(cls, path_or_text: str | os.PathLike):
        """Load :meth:`to_json`'s text or file.

        Parameters
        ----------
        path_or_text : str or os.PathLike
            A JSON text (starting with ``{``) or a file's path.

        Returns
        -------
        PlainResult
        """
        return load_json_result(cls, path_or_text)


register_record(ResidualCheck)
register_record(Diagnosis)
