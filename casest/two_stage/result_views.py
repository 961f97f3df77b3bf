"""What an :class:`casest.Estimate` offers beyond its fields: which standard deviations to
report, its figures and its validation on another record (a mixin, so that the result's
fields and file format stay in :mod:`casest.two_stage.result`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import OptionError
from ..estimation.verdict import residual_verdict
from ..status import CheckCode, ResidualCode


__all__ = ["EstimateViews", "StdChoice"]


@dataclass(frozen=True)
class StdChoice:
    """Which standard deviations an estimate's report should carry (:meth:`Estimate.std_choice`).

    Attributes
    ----------
    kind : {"ml", "colored"}
        The ML (Cramer-Rao) std, or the colored-residual std.
    std : ndarray, shape (n_parameters,)
    reason : str
        Why, in words a report can print.
    """

    kind: str
    std: np.ndarray
    reason: str


class EstimateViews:
    """The std choice, figures and validation of an estimate (mixed into :class:`casest.Estimate`)."""

    # -- which std ------------------------------------------------------------------------
    def std_choice(self) -> "StdChoice":
        """The standard deviations to report, and why.

        The ML std (the inverse information, the Cramer-Rao bound) assumes white residuals.
        When the residual tests say the noise is coloured (correlated in time, independent of
        the signals, the fitted value and time: :mod:`casest.estimation.verdict`), those std are
        too small: the colored-residual std of :attr:`residual_analysis` (Morelli-Klein, the
        information's sandwich with the residuals' autocovariance) are then the ones to report.
        When the residuals depend on something (a model error) no std describes the right model;
        where they are correlated in time too, the colored-residual std are still the less
        optimistic ones and are returned, with that reason.

        Returns
        -------
        StdChoice
        """
        verdict = residual_verdict(self.residual_checks)
        analysis = self.residual_analysis
        usable = analysis is not None and tuple(analysis.parameter_names) == tuple(self.parameter_names)
        if verdict.code is ResidualCode.COLOURED and usable:
            return StdChoice("colored", np.asarray(analysis.colored_std, dtype=float),
                             f"{verdict.finding()}: the colored-residual std allow for it; the ML std would be too "
                             "small by the ratio shown")
        if verdict.code is ResidualCode.COLOURED:
            return StdChoice("ml", self.std, f"{verdict.finding()}, but no colored-residual std exists for this "
                             "estimate: the ML std are too small")
        coloured = any(c.code is CheckCode.WHITENESS for c in verdict.failed)
        if verdict.code is ResidualCode.DEPENDENT and coloured and usable:
            return StdChoice("colored", np.asarray(analysis.colored_std, dtype=float),
                             f"{verdict.finding()}: a model error, which no std allows for; the residuals are "
                             "correlated in time, and the colored-residual std are the less optimistic ones")
        if verdict.code is ResidualCode.DEPENDENT:
            return StdChoice("ml", self.std, f"{verdict.finding()}: a model error, which no std allows for")
        return StdChoice("ml", self.std, "the residuals pass the whiteness tests and the tests of independence: the ML std "
                         "(Cramer-Rao bound) stands")

    # -- figures and validation -----------------------------------------------------------
    def plot_fit(self, model, data, title: str | None = None):
        """Measured against estimated outputs, one column per record (manoeuvre); for a dynamic
        model a last row with each channel's residual autocorrelation.

        Parameters
        ----------
        model : Model or DynamicModel
            The model estimated (a record's per-manoeuvre initial states are taken by name).
        data : Dataset, sequence of Dataset or mapping of str to Dataset
        title : str, optional

        Returns
        -------
        matplotlib.figure.Figure
        """
        from ..estimation.figures import fit_figure

        return fit_figure(model, self, data, analysis=self.residual_analysis, title=title)

    def plot_residuals(self, model, data, max_lag: int = 50):
        """Residual time histories per record and output, with their autocorrelation.

        Parameters
        ----------
        model : Model or DynamicModel
        data : Dataset, sequence of Dataset or mapping of str to Dataset
        max_lag : int

        Returns
        -------
        matplotlib.figure.Figure
        """
        from ..estimation.figures import residuals_figure

        return residuals_figure(model, self, data, max_lag)

    def plot_convergence(self):
        """Each parameter with its std band, and the cost, over stage 2's iterations.

        Returns
        -------
        matplotlib.figure.Figure

        Raises
        ------
        OptionError
            Stage 2 did not record its iterates (:attr:`convergence` is None).
        """
        from ..estimation.figures import convergence_figure

        if self.convergence is None:
            raise OptionError("this estimate's stage 2 did not record its iterates: estimate with "
                              "solver_settings=casest.SolverSettings(record_iterates=True) (IPOPT records them then; "
                              "Gauss-Newton output error always does, Levenberg-Marquardt on small static problems never)")
        units = dict(zip(self.parameter_names, self.parameter_units or ("",) * len(self.parameter_names)))
        names = self.convergence.parameter_names
        return convergence_figure(self.convergence, names, [units.get(n, "") for n in names])

    def plot_correlation(self, title: str | None = None):
        """The correlation matrix of the estimates (:attr:`correlation`) as a colour map.

        Parameters
        ----------
        title : str, optional

        Returns
        -------
        matplotlib.figure.Figure
        """
        from ..estimation.figures import correlation_figure

        return correlation_figure(self.correlation, self.parameter_names, title)

    def validate(self, model, data):
        """The model with these estimates against a record it was not estimated from.

        Parameters
        ----------
        model : Model or DynamicModel
        data : Dataset

        Returns
        -------
        Validation
            Prediction error, Theil's inequality coefficient and R^2 per output
            (:mod:`casest.estimation.validation`).
        """
        from ..estimation.validation import validate

        return validate(model, self, data)

    def parameters_frame(self):
        """The parameters as a pandas data frame (needs ``casest[frames]``).

        Returns
        -------
        pandas.DataFrame
            One row per parameter (index ``parameter``): ``value``, ``std`` (NaN where there is
            none), ``unit``, ``lower`` and ``upper`` (the bounds), ``at_bound`` (``"lower"``,
            ``"upper"`` or ``""``) and ``std_note`` (why there is no std, or ``""``); with
            profile intervals attached, also ``interval_lower`` and ``interval_upper`` (NaN for a
            parameter without one).
        """
        from ..data.frames import require_pandas

        pandas = require_pandas()
        names = list(self.parameter_names)
        units = list(self.parameter_units) if self.parameter_units else [""] * len(names)
        frame = pandas.DataFrame({"value": np.asarray(self.theta, dtype=float), "std": np.asarray(self.std, dtype=float),
                                 "unit": units, "lower": np.asarray(self.lower_bounds, dtype=float),
                                 "upper": np.asarray(self.upper_bounds, dtype=float),
                                 "at_bound": [side or "" for side in self.active_bounds],
                                 "std_note": [reason or "" for reason in self.std_reasons]},
                                index=pandas.Index(names, name="parameter"))
        intervals = {item.name: item for item in getattr(self, "intervals", ())}
        if intervals:
            frame["interval_lower"] = [intervals[n].lower if n in intervals else np.nan for n in names]
            frame["interval_upper"] = [intervals[n].upper if n in intervals else np.nan for n in names]
        return frame

    def noise_frame(self):
        """The noise as a pandas data frame (needs ``casest[frames]``).

        Returns
        -------
        pandas.DataFrame
            One row per output (index ``output``): ``variance`` (R, unit squared), ``std``
            (its square root) and ``unit``.
        """
        from ..data.frames import require_pandas

        pandas = require_pandas()
        names = list(self.output_names)
        units = list(self.output_units) if self.output_units else [""] * len(names)
        R = np.asarray(self.R, dtype=float)
        return pandas.DataFrame({"variance": R, "std": np.sqrt(R), "unit": units},
                                index=pandas.Index(names, name="output"))

    def to_dataframe(self):
        """The estimate's parameter table as a pandas data frame: :meth:`parameters_frame`
        (the noise: :meth:`noise_frame`).

        Returns
        -------
        pandas.DataFrame
        """
        return self.parameters_frame()
