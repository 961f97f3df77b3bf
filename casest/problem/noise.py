"""Noise models of the measurement ``z = h + v``, ``v ~ N(0, R)``: how R enters the ML cost.

Each noise model is a class that carries its own behaviour, so that the stages ask it
instead of testing which one it is:

- :class:`DiagonalNoise` (the default, paper Eq. 6): R diagonal and unknown, estimated with
  theta; the decision vector holds ``ln R_j``, bounded below by the noise floor.
- :class:`KnownNoise`: R diagonal and given; stage 1 ranks by the weighted residuals, stage 2
  is the weighted least squares (``ln R`` held), the std follow from the given R.
- :class:`CorrelatedNoise`: R full and unknown, ``R = L L'`` in log-Cholesky form, estimated
  with all of theta (full mode), complete data only.

What each knows: the length of its block in the decision vector and its maps to and from R
(:meth:`NoiseModel.to_vector`, :meth:`NoiseModel.from_vector`), the ML value of R at a
parameter value (the profile), where stage 2 starts and its bounds, its symbols in an
embedded NLP, the stage-1 weighting, and the words of the report.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import casadi as ca
import numpy as np

from ..backend.linalg import cholesky_factor, cholesky_vector, covariance_of, n_cholesky
from ..backend.noise_terms import CHOLESKY, DIAGONAL, NoiseTerm
from ..errors import DataError, ModelError
from ..models import Model


__all__ = ["NoiseModel", "DiagonalNoise", "KnownNoise", "CorrelatedNoise", "cholesky_factor", "n_cholesky",
           "cholesky_vector", "covariance_of"]


# ----------------------------------------------------------------------------- the noise models
class NoiseModel:
    """How the noise covariance R enters the ML cost (base of the three noise models).

    Attributes
    ----------
    kind : str
        A label for reports and saved results (``"diagonal"``, ``"known"``, ``"full"``);
        code decides with the attributes below, never with this label.
    estimated : bool
        R is estimated with theta (False: R is given and held).
    term : NoiseTerm
        R's parametrisation in the cost, the sums and the information matrix
        (:mod:`casest.backend.noise_terms`: diagonal ``ln R`` or log-Cholesky).
    """

    kind = ""
    estimated = True
    term: NoiseTerm = DIAGONAL

    def bind(self, model: Model) -> "NoiseModel":
        """Check the noise model against a model's outputs; returns itself.

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        NoiseModel

        Raises
        ------
        OptionError
            Outputs named that the model does not have, or outputs without a given noise.
        """
        return self

    def given_variances(self, model: Model) -> np.ndarray | None:
        """The given diagonal of R, shape (n_outputs,), or None when R is estimated.

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        ndarray, shape (n_outputs,), or None
        """
        return None

    def for_experiments(self, output_names, experiments) -> "NoiseModel":
        """The noise model of several experiments with one R each (outputs ``output@experiment``).

        Parameters
        ----------
        output_names : sequence of str
            The declared outputs.
        experiments : sequence of str
            The experiments' names.

        Returns
        -------
        NoiseModel
        """
        return self

    def for_declared_outputs(self, output_names, experiments) -> "NoiseModel":
        """Inverse of :meth:`for_experiments` where it exists (the same noise in every experiment).

        Parameters
        ----------
        output_names : sequence of str
        experiments : sequence of str

        Returns
        -------
        NoiseModel
        """
        return self

    def vector_size(self, n_outputs: int) -> int:
        """Length of the noise block of stage 2's decision vector (``ln R_j``: n_outputs).

        Parameters
        ----------
        n_outputs : int

        Returns
        -------
        int
        """
        return self.term.block_size(n_outputs)

    def to_vector(self, R) -> np.ndarray:
        """The noise block for R: ``ln R_j`` of the diagonal R, shape (n_outputs,).

        Parameters
        ----------
        R : array_like, shape (n_outputs,) (a full R: (n_outputs, n_outputs))

        Returns
        -------
        ndarray, shape (vector_size(n_outputs),)
        """
        return self.term.block_of(R)

    def from_vector(self, vector, n_outputs: int) -> np.ndarray:
        """Inverse of :meth:`to_vector`: the diagonal of R, shape (n_outputs,), or the full R.

        Parameters
        ----------
        vector : array_like, shape (vector_size(n_outputs),)
        n_outputs : int

        Returns
        -------
        ndarray, shape (n_outputs,) (a full R: (n_outputs, n_outputs))
        """
        return self.term.covariance_of_block(vector, n_outputs)

    def profile(self, problem, theta) -> np.ndarray:
        """The R that minimises J at ``theta`` (the known R when R is given).

        Parameters
        ----------
        problem : Problem
        theta : mapping or array_like

        Returns
        -------
        ndarray, shape (n_outputs,) (a full R: (n_outputs, n_outputs))
        """
        return np.maximum(problem.residual_mean_square(theta), 1e-300)

    def start(self, problem, theta0, floor: np.ndarray, R0=None) -> np.ndarray:
        """Where stage 2 starts R: ``R0`` if given, else the ML R at ``theta0``, held above ``floor``.

        Parameters
        ----------
        problem : Problem
        theta0 : mapping or array_like
        floor : ndarray, shape (n_outputs,)
            Lower bounds of the variances.
        R0 : array_like, optional

        Returns
        -------
        ndarray, shape (n_outputs,) (a full R: (n_outputs, n_outputs))
        """
        R = problem.residual_mean_square(theta0) if R0 is None else np.asarray(R0, dtype=float).reshape(-1)
        return np.maximum(R, floor)

    def stage2_bounds(self, floor: np.ndarray, R0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the noise block in stage 2 (``ln R_j >= ln floor_j``).

        Parameters
        ----------
        floor : ndarray, shape (n_outputs,)
        R0 : ndarray
            The start (a held R is bounded to it).

        Returns
        -------
        lower, upper : ndarray, shape (vector_size(n_outputs),) each
        """
        return np.log(floor), np.full(floor.size, np.inf)

    def decision_bounds(self, floor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the noise variables of an embedded NLP (:meth:`symbols`), which leaves out a held R.

        Parameters
        ----------
        floor : ndarray, shape (n_outputs,)

        Returns
        -------
        lower, upper : ndarray
        """
        return self.stage2_bounds(floor, None)

    def decision_vector(self, R) -> np.ndarray:
        """The noise variables of an embedded NLP (:meth:`symbols`) for R; empty when R is held.

        Parameters
        ----------
        R : array_like, shape (n_outputs,) (a full R: (n_outputs, n_outputs))

        Returns
        -------
        ndarray
        """
        return self.to_vector(R)

    def decision_covariance(self, variables, model: Model) -> np.ndarray:
        """Inverse of :meth:`decision_vector`: R from the noise variables (a held R: the given one).

        Parameters
        ----------
        variables : array_like
        model : Model or DynamicModel

        Returns
        -------
        ndarray, shape (n_outputs,) (a full R: (n_outputs, n_outputs))
        """
        return self.from_vector(variables, model.n_outputs)

    def cost_block(self, variables, model: Model):
        """The noise block the cost takes, from the noise variables of an embedded NLP (a held R: its
        fixed block, whatever the variables).

        Parameters
        ----------
        variables : casadi.MX
        model : Model or DynamicModel

        Returns
        -------
        casadi.MX or casadi.DM
        """
        return variables

    def symbols(self, model: Model) -> tuple:
        """The noise part of an embedded NLP: ``(vector, variables, R)`` where ``vector`` enters
        the sums, ``variables`` is the decision block (None when R is held) and ``R`` the
        covariance expression (diagonal: a column).

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        vector : casadi.MX
        variables : casadi.MX or None
        R : casadi.MX
        """
        rho = ca.MX.sym("rho", model.n_outputs)
        return rho, rho, ca.exp(rho)

    def start_expression(self, variances, floor):
        """The decision block's start for variances ``max(variances, floor)`` as CasADi
        expressions (column vectors of length n_outputs), or None when R is held.

        Parameters
        ----------
        variances : casadi.MX, shape (n_outputs, 1)
        floor : casadi.MX, shape (n_outputs, 1)

        Returns
        -------
        casadi.MX or None
        """
        return ca.log(ca.fmax(variances, floor))

    def bounds_expression(self, floor) -> tuple:
        """:meth:`decision_bounds` for a floor given as a CasADi expression.

        Parameters
        ----------
        floor : casadi.MX, shape (n_outputs, 1)

        Returns
        -------
        lower, upper : casadi.MX or casadi.DM
        """
        return ca.log(floor), ca.DM.inf(floor.numel())

    def variable_names(self, output_names) -> list:
        """Names of the decision variables of :meth:`symbols`.

        Parameters
        ----------
        output_names : sequence of str

        Returns
        -------
        list of str
        """
        return [f"ln_R[{c}]" for c in output_names]

    def floor_constraint(self, variables, floor):
        """The noise floor as a constraint expression ``>= 0`` on the decision block, or None.

        Parameters
        ----------
        variables : casadi.MX
            The decision block of :meth:`symbols`.
        floor : casadi.MX, shape (n_outputs, 1)

        Returns
        -------
        casadi.MX or None
        """
        return variables - floor

    def stage1_weights(self, model: Model) -> np.ndarray | None:
        """Per-output weights applied to outputs and residuals in stage 1 (None: unweighted).

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        ndarray, shape (n_outputs,), or None
        """
        return None

    def check_data(self, data) -> None:
        """Refuse data the noise model cannot take (a full R needs every output at every sample).

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        None

        Raises
        ------
        DataError
            Data this noise model cannot take.
        """

    def describe(self, model: Model) -> str:
        """One line for reports.

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        str
        """
        return "unknown diagonal R (estimated)"


@dataclass(frozen=True)
class DiagonalNoise(NoiseModel):
    """Unknown, independent measurement noise: R diagonal, estimated with theta (the default,
    paper Eq. 6).

    Attributes
    ----------
    kind : str
        ``"diagonal"``.
    estimated : bool
        True.
    term : NoiseTerm
        :data:`casest.backend.noise_terms.DIAGONAL`.

    Examples
    --------
    >>> casest.estimate(model, data, noise=casest.DiagonalNoise())  # doctest: +SKIP
    """

    kind = "diagonal"


@dataclass(frozen=True)
class KnownNoise(NoiseModel):
    """Known, independent measurement noise: one standard deviation per output channel.

    With a known R the ML cost has no ln|R| term to estimate: stage 1 ranks candidates by
    the weighted residuals (weights 1/R), stage 2 is the weighted least squares, and the
    standard deviations come from the given R.

    Parameters
    ----------
    std : mapping of str to float
        Output name -> noise standard deviation (output unit, > 0). Every output must be
        given.

    Examples
    --------
    >>> casest.estimate(model, data, noise=casest.KnownNoise({"z": 0.3}))  # doctest: +SKIP
    """

    std: Mapping[str, float]
    kind = "known"
    estimated = False

    def variances(self, model: Model) -> np.ndarray:
        """The diagonal of R in the model's output order, shape (n_outputs,), output unit squared.

        Raises
        ------
        ModelError
            A missing or unknown output name, or a std that is not positive and finite.

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        ndarray, shape (n_outputs,)
        """
        std = dict(self.std)
        unknown = [k for k in std if k not in model.output_names]
        missing = [k for k in model.output_names if k not in std]
        if unknown or missing:
            raise ModelError(
                f"KnownNoise needs one std per output {list(model.output_names)}"
                + (f"; unknown: {unknown}" if unknown else "") + (f"; missing: {missing}" if missing else "")
            )
        values = []
        for name in model.output_names:
            value = std[name]
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
                    or not math.isfinite(value) or value <= 0:
                raise ModelError(f"KnownNoise: the std of {name!r} must be a positive finite number, got {value!r}")
            values.append(float(value) ** 2)
        return np.array(values)

    def bind(self, model: Model) -> "KnownNoise":
        self.variances(model)
        return self

    def given_variances(self, model: Model) -> np.ndarray:
        return self.variances(model)

    def for_experiments(self, output_names, experiments) -> "KnownNoise":
        if not set(self.std) <= set(output_names):
            return self  # given per output and experiment already
        # one std per declared output applies to that output in every experiment
        return KnownNoise({f"{o}@{e}": self.std[o] for e in experiments for o in output_names})

    def for_declared_outputs(self, output_names, experiments) -> "KnownNoise":
        std, first = dict(self.std), experiments[0]
        if all(std.get(f"{o}@{e}") == std.get(f"{o}@{first}") for e in experiments for o in output_names):
            return KnownNoise({o: std[f"{o}@{first}"] for o in output_names})
        return self

    def _R(self, problem) -> np.ndarray:
        return self.variances(problem.model)

    def profile(self, problem, theta) -> np.ndarray:
        return self._R(problem)

    def start(self, problem, theta0, floor, R0=None) -> np.ndarray:
        return self._R(problem).copy()

    def stage2_bounds(self, floor, R0) -> tuple[np.ndarray, np.ndarray]:
        held = np.log(np.asarray(R0, dtype=float).reshape(-1))  # equal bounds: IPOPT holds R
        return held, held.copy()

    def decision_bounds(self, floor) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros(0), np.zeros(0)

    def decision_vector(self, R) -> np.ndarray:
        return np.zeros(0)

    def decision_covariance(self, variables, model: Model) -> np.ndarray:
        return self.variances(model)

    def cost_block(self, variables, model: Model):
        return ca.DM(np.log(self.variances(model)))

    def symbols(self, model: Model) -> tuple:
        R = self.variances(model)
        return ca.DM(np.log(R)), None, ca.MX(ca.DM(R))

    def variable_names(self, output_names) -> list:
        return []

    def start_expression(self, variances, floor):
        return None

    def bounds_expression(self, floor) -> tuple:
        return ca.DM.zeros(0), ca.DM.zeros(0)

    def floor_constraint(self, variables, floor):
        return None

    def stage1_weights(self, model: Model) -> np.ndarray:
        return 1.0 / np.sqrt(self.variances(model))

    def describe(self, model: Model) -> str:
        return "known R (" + ", ".join(f"{n}: std {s:.6g}" for n, s in zip(model.output_names, np.sqrt(self.variances(model)))) + ")"


@dataclass(frozen=True)
class CorrelatedNoise(NoiseModel):
    """Unknown noise with a full covariance R (correlated channels), estimated with theta.

    R = L L' with L lower triangular and log-parametrised diagonal (log-Cholesky); stage 2
    runs in full mode with the exact Hessian in (theta, L), and the standard deviations
    account for R being estimated. Needs complete data (no missing outputs).

    Attributes
    ----------
    kind : str
        ``"full"``.
    estimated : bool
        True.
    term : NoiseTerm
        :data:`casest.backend.noise_terms.CHOLESKY`.

    Examples
    --------
    >>> casest.estimate(model, data, noise=casest.CorrelatedNoise())  # doctest: +SKIP
    """

    kind = "full"
    term = CHOLESKY

    def profile(self, problem, theta) -> np.ndarray:
        return problem.residual_covariance(theta)

    def start(self, problem, theta0, floor, R0=None) -> np.ndarray:
        return problem.residual_covariance(theta0) + np.diag(floor) if R0 is None else np.asarray(R0, dtype=float)

    def stage2_bounds(self, floor, R0) -> tuple[np.ndarray, np.ndarray]:
        ny = floor.size
        extra = n_cholesky(ny) - ny
        return (np.concatenate([0.5 * np.log(floor), np.full(extra, -np.inf)]),  # ln L_jj >= ln(floor_j) / 2
                np.full(ny + extra, np.inf))

    def symbols(self, model: Model) -> tuple:
        ny = model.n_outputs
        ell = ca.MX.sym("ell", n_cholesky(ny))
        L = cholesky_factor(ell, ny)
        return ell, ell, ca.mtimes(L, L.T)

    def start_expression(self, variances, floor):
        ny = floor.numel()
        return ca.vertcat(0.5 * ca.log(ca.fmax(variances, floor)), ca.DM.zeros(n_cholesky(ny) - ny))

    def bounds_expression(self, floor) -> tuple:
        ny = floor.numel()
        extra = n_cholesky(ny) - ny
        return ca.vertcat(0.5 * ca.log(floor), -ca.DM.inf(extra)), ca.DM.inf(ny + extra)

    def variable_names(self, output_names) -> list:
        ny = len(output_names)
        return [f"ln_L[{c},{c}]" for c in output_names] + [
            f"L[{output_names[i]},{output_names[j]}]" for j in range(ny) for i in range(j + 1, ny)]

    def floor_constraint(self, variables, floor):
        return 2 * variables[: floor.numel()] - floor

    def check_data(self, data) -> None:
        if data.has_missing:
            raise DataError("a full unknown R needs complete data (every output at every sample); drop the "
                            "samples with missing outputs or use the diagonal R")

    def describe(self, model: Model) -> str:
        return "unknown full R (estimated, log-Cholesky)"
