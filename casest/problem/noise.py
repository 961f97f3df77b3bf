"""Noise models of the measurement ``z = h + v``, ``v ~ N(0, R)``: how R enters the ML cost.

Each noise model is a class that carries its own behaviour, so that the stages ask it
instead of testing which one it is (the interface: :class:`NoiseModel`,
:mod:`casest.problem.noise_model`):

- :class:`DiagonalNoise` (the default, paper Eq. 6): R diagonal and unknown, estimated with
  theta; the decision vector holds ``ln R_j``, bounded below by the noise floor.
- :class:`KnownNoise`: R diagonal and given; stage 1 ranks by the weighted residuals, stage 2
  is the weighted least squares (``ln R`` held), the std follow from the given R.
- :class:`CorrelatedNoise`: R full and unknown, ``R = L L'`` in log-Cholesky form, estimated
  with all of theta (full mode), complete data only.

What each knows: its noise term (:mod:`casest.backend.noise_terms`: the per-sample cost and
the information weighting), the length of its block in the decision vector and its maps to
and from R (:meth:`NoiseModel.to_vector`, :meth:`NoiseModel.from_vector`), the ML value of R
at a parameter value (the profile), where stage 2 starts, its mode and bounds, what the
standard deviations hold, its symbols in an embedded NLP, the stage-1 weighting, and the
words of the report.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import casadi as ca
import numpy as np

from ..backend.linalg import cholesky_factor, cholesky_vector, covariance_of, n_cholesky
from ..backend.noise_terms import CHOLESKY
from ..errors import DataError, ModelError, OptionError
from ..models import Model
from .noise_model import NoiseModel


__all__ = ["NoiseModel", "DiagonalNoise", "KnownNoise", "CorrelatedNoise", "cholesky_factor", "n_cholesky",
           "cholesky_vector", "covariance_of"]


# ----------------------------------------------------------------------------- the noise models
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

    def __post_init__(self):
        if not isinstance(self.std, Mapping):
            raise ModelError(f"KnownNoise takes a mapping of output name to noise std, e.g. KnownNoise({{'z': 0.3}}), "
                             f"got {type(self.std).__name__} {self.std!r}")

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
        return self.symbols(model)[0]  # the held block, whatever the variables

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

    def stage2_mode(self, mode: str) -> str:
        return "reduced" if mode == "alternating" else mode

    def solved_covariance(self, R_start: np.ndarray, R_solved: np.ndarray) -> np.ndarray:
        return np.asarray(R_start, dtype=float).copy()

    def floor_channels(self, r_at_floor, n_outputs: int) -> np.ndarray:
        return np.zeros(n_outputs, dtype=bool)  # the given R stands

    def held_rows(self, floor_channels: np.ndarray) -> np.ndarray:
        return np.ones(floor_channels.size, dtype=bool)  # every ln R_j held at the given R

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

    def std_covariance(self, R) -> np.ndarray:
        R = np.asarray(R, dtype=float)
        if R.ndim != 2:
            raise OptionError("a Problem with CorrelatedNoise needs the full R (n_outputs x n_outputs)")
        return R.copy()

    def floor_channels(self, r_at_floor, n_outputs: int) -> np.ndarray:
        return np.zeros(n_outputs, dtype=bool)  # a full R's block is bounded on L_jj, not held

    def for_experiments(self, output_names, experiments) -> "CorrelatedNoise":
        raise OptionError("a full unknown R per experiment is not offered: use separate_noise=False "
                          "(--shared-noise; one full R for all experiments) or estimate the experiments one at a time")

    def check_data(self, data) -> None:
        if data.has_missing:
            raise DataError("a full unknown R needs complete data (every output at every sample); drop the "
                            "samples with missing outputs or use the diagonal R")

    def describe(self, model: Model) -> str:
        return "unknown full R (estimated, log-Cholesky)"
