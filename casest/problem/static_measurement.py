"""The measurement of a static :class:`casest.Model`: ``z_k = h(x_k, theta) + v_k``."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings
from ..backend.noise_terms import NoiseTerm
from ..backend.sums import (
    Record,
    data_outside_graph,
    map_sum,
    ml_sums,
    prediction_and_jacobian,
    residual_jacobian,
    symmetric,
)
from .._casadi.memory import StructureCache
from ..data.dataset import Dataset
from ..models import Model
from .data_graph import static_data_views, ml_cost_expression, sum_data_symbols
from .experiments import stack_experiments
from .measurement_base import Measurement

#: ``(theta, noise, data) -> (J, H)`` per model structure and data layout (building one costs ~1 ms)
_HESSIANS = StructureCache()


__all__ = ['StaticMeasurement']


class StaticMeasurement(Measurement):
    """A static :class:`casest.Model`: ``z_k = h(x_k, theta) + v_k`` with measured signals x_k.

    Parameters
    ----------
    model : Model
    """

    @property
    def controlled_names(self) -> tuple:
        return tuple(self.model.signal_names)

    def controlled_history(self, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        return data.signals.T.copy(), np.arange(data.n_samples, dtype=float)

    def information_arguments(self, history, times, data: Dataset) -> dict:
        return {"signals": history}

    def stack_experiments(self, experiments, separate_noise: bool) -> tuple:
        return stack_experiments(self.model, experiments, separate_noise)

    def predict(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        return self.model.predict(theta, data.signals)

    def signals_at(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        return data.signals

    @property
    def cost_model(self) -> Model:
        return self.output_model

    def prediction_and_jacobian(self, theta: np.ndarray, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        return prediction_and_jacobian(self.model, data.signals, theta)

    def prediction_blocks(self, theta: np.ndarray, data: Dataset, block_samples: int):
        for start in range(0, data.n_samples, max(1, int(block_samples))):
            block = data.subset(slice(start, start + block_samples))
            yield (*prediction_and_jacobian(self.model, block.signals, theta), block.output_mask().reshape(-1))

    def jacobian(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        return residual_jacobian(self.model, data, theta)

    def data_vector(self, data: Dataset, masked: bool) -> np.ndarray:
        return np.concatenate([data.signals.reshape(-1), self.outputs_of(data, masked).reshape(-1)])

    def dataset_from_vector(self, p, n_samples: int, masked: bool) -> Dataset:
        p = np.asarray(p, dtype=float).reshape(-1)
        ns, nz = self.model.n_signals, self.model.n_outputs * (2 if masked else 1)
        X, Z = p[:ns * n_samples].reshape(n_samples, ns), p[ns * n_samples:].reshape(n_samples, nz)
        return Dataset.from_arrays(self.model, X, self._outputs_from(Z, masked), missing="allow" if masked else "error")

    def data_outside_graph(self, n_samples: int) -> bool:
        return data_outside_graph(n_samples)

    def record(self, data: Dataset, masked: bool) -> Record:
        return Record(data.signals, self.outputs_of(data, masked))

    def _prediction_expression(self, n_samples: int, theta, p, masked: bool) -> tuple:
        X, Z = static_data_views(self.model, n_samples, masked, p)
        return self.model.function.map(n_samples)(X, theta), Z

    def cost_expression(self, n_samples: int, theta, noise, p, masked: bool, noise_term: NoiseTerm, penalty) -> ca.MX:
        return ml_cost_expression(self.model, n_samples, theta, noise, p, masked, noise_term, penalty)

    def information_expression(self, n_samples: int, noise_term: NoiseTerm, theta: ca.MX) -> tuple[list, ca.MX]:
        model = self.model
        ny = model.n_outputs
        J = ca.jacobian(model.h, model.theta)  # ny x n
        weight = ca.SX.sym("weight")
        Rinv = noise_term.covariance_symbol(ny, "Rinv", ca.SX)
        WJ = noise_term.weigh(Rinv, J)
        per_sample = ca.Function("information_i", [model.x, weight, model.theta, Rinv],
                                 [weight * ca.mtimes(J.T, WJ)], ["x", "weight", "theta", "Rinv"], ["F"])
        X = ca.MX.sym("signals", model.n_signals, n_samples)
        w = ca.MX.sym("weights", 1, n_samples)
        R = noise_term.covariance_symbol(ny)
        F = map_sum(per_sample, n_samples, 1, "information_sum")(X, w, theta, noise_term.inverse(R))
        return [("signals", X), ("R", R), ("weights", w)], F

    def cost_hessian(self, n_samples: int, masked: bool, noise_term: NoiseTerm, threads=None, jit=False,
                     jit_flags=("-O2",)) -> ca.Function:
        scale = self.model.scales
        key = ("cost_hessian", n_samples, bool(masked), noise_term, threads, bool(jit),
               tuple(jit_flags), tuple(scale))
        cache = _HESSIANS.setdefault(self.model, {})
        if key not in cache:
            cache[key] = self._cost_hessian(n_samples, masked, noise_term, threads, jit, jit_flags)
        return cache[key]

    def _cost_hessian(self, n_samples, masked, noise_term, threads, jit, jit_flags) -> ca.Function:
        # the sums stage 2 compiled (same scale, threads and flags), so no second compile:
        # with w = [theta / scale; rho], H_theta = T H_w T, T = diag(1 / scale, 1)
        scale = self.model.scales
        sums = ml_sums(self.model, n_samples, scale, threads, jit, jit_flags, masked, noise_term,
                       bound=data_outside_graph(n_samples))
        n_noise = noise_term.block_size(self.model.n_outputs)
        p, data = sum_data_symbols(self.model, n_samples, masked)
        theta = ca.MX.sym("theta", self.model.n_parameters)
        rho = ca.MX.sym("rho", n_noise)
        w = ca.vertcat(theta / ca.DM(scale), rho)
        T = ca.DM(np.diag(np.concatenate([1.0 / scale, np.ones(n_noise)])))
        J = sums.cost(w, *data) * n_samples
        H = T @ symmetric(sums.hessian(w, *data)) @ T * n_samples
        return ca.Function("J_hess", [theta, rho, p], [J, H], ["theta", "rho", "data"], ["J", "H"])

    def ml_sums(self, n_samples: int, scale, threads, jit, jit_flags, masked: bool, noise_term: NoiseTerm):
        return ml_sums(self.model, n_samples, scale, threads, jit, jit_flags, masked, noise_term)

    def cost_sums(self, n_samples: int, masked: bool, noise_term: NoiseTerm, bound: bool) -> tuple:
        # stage 2's sums under default settings (its scale, threads and compile): one build and
        # one compiled library serve the start costs and the solve
        settings, scale = SolverSettings(), self.model.scales
        return ml_sums(self.model, n_samples, scale, settings.resolved_threads(n_samples), settings.resolved_jit(n_samples),
                       settings.jit_flags, masked, noise_term, bound=bound), scale
