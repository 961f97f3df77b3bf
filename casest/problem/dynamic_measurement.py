"""The measurement of a :class:`casest.DynamicModel`: outputs of states simulated from theta."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..backend.noise_terms import NoiseTerm
from ..backend.ipopt import SolverSettings
from ..backend.sensitivities import output_sensitivities
from ..backend.output_error import (dynamic_cost_expression, dynamic_data_views, output_error_sums, prediction_model,
                                    prefetch_second_order, sensitivity_flags)
from ..backend.sums import Record, ml_sums, symmetric
from ..data.dataset import Dataset
from ..models import Model, OptionError
from .experiments import stack_dynamic_experiments
from .measurement_base import Measurement


__all__ = ['DynamicMeasurement']


class DynamicMeasurement(Measurement):
    """A :class:`casest.DynamicModel`: outputs of states simulated from theta (output error).

    Parameters
    ----------
    model : DynamicModel
    """

    simulated = True
    full_mode_reason = "output error simulates the states from all of theta"

    @property
    def output_model(self) -> Model:
        return self.model.output_model

    @property
    def through_states(self) -> tuple:
        """The parameters that can never be linear: those of the dynamics and the output delays."""
        delays = [n for n in self.model.output_delays.parameter_names if n not in self.model.dynamic_parameters]
        return tuple(self.model.dynamic_parameters) + tuple(delays)

    @property
    def model_has_forward_sensitivities(self) -> bool:
        """The exact per-sample sums of :class:`casest.backend.OutputErrorSums` apply: an RK4 model
        whose outputs are each sample's own (no output delays, which mix neighbouring samples)."""
        return self.model.integrator == "rk4" and not self.model.output_delays

    @property
    def controlled_names(self) -> tuple:
        return tuple(u.name for u in self.model.inputs)

    def controlled_history(self, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        return data.signals[:, 1:].T.copy(), data.signals[:, 0]

    def information_arguments(self, history, times, data: Dataset) -> dict:
        args = {"t": ca.DM(times).T, "inputs": history}
        if self.model.initial_from_data:
            args["x0_data"] = ca.DM(self.model.initial_values(data))
        return args

    def stack_experiments(self, experiments, separate_noise: bool) -> tuple:
        return stack_dynamic_experiments(self.model, experiments, separate_noise)

    def check_data(self, data: Dataset) -> None:
        self.model.check_data(data)

    def predict(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        return self.model.predict_data(theta, data)

    def signals_at(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        states, outputs = self.model.simulate(theta, data)
        return outputs if self.model.output_delays else np.hstack([states, data.signals[:, 1:]])

    @property
    def cost_model(self) -> Model:
        return prediction_model(self.model) if self.model.output_delays else self.model.output_model

    def prediction_blocks(self, theta: np.ndarray, data: Dataset, block_samples: int):
        yield (*self.prediction_and_jacobian(theta, data), data.output_mask().reshape(-1))

    def prediction_and_jacobian(self, theta: np.ndarray, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        if self.model.integrator != "rk4":
            return self.model.prediction_and_jacobian(data, theta)
        N = data.n_samples
        masked = data.has_missing
        defaults = SolverSettings()  # as Gauss-Newton with default settings: one compiled pass shared
        sens = output_sensitivities(self.model, N, masked, defaults.resolved_jit(N),
                                    sensitivity_flags(defaults.jit_flags))
        y, J = sens(self.model.vector(theta), self.data_vector(data, masked))
        return y.reshape(-1), J.reshape(N * self.model.n_outputs, -1)

    def jacobian(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        return self.prediction_and_jacobian(theta, data)[1]

    def data_vector(self, data: Dataset, masked: bool) -> np.ndarray:
        return np.concatenate([data.signals[:, 0], data.signals[:, 1:].reshape(-1),
                               self.outputs_of(data, masked).reshape(-1), self.model.initial_values(data)])

    def dataset_from_vector(self, p, n_samples: int, masked: bool) -> Dataset:
        model, N = self.model, n_samples
        p = np.asarray(p, dtype=float).reshape(-1)
        nu, nz = len(model.inputs), model.n_outputs * (2 if masked else 1)
        t, U = p[:N], p[N:N + nu * N].reshape(N, nu)
        Z = self._outputs_from(p[N + nu * N:N + (nu + nz) * N].reshape(N, nz), masked)
        columns = {model.time: t, **{u.name: U[:, j] for j, u in enumerate(model.inputs)},
                   **{o: Z[:, j] for j, o in enumerate(model.output_names)},
                   **{s: np.full(N, v) for s, v in zip(model.initial_from_data, p[N + (nu + nz) * N:])}}
        return model.dataset(columns, missing="allow" if masked else "error")

    def data_outside_graph(self, n_samples: int) -> bool:
        return False

    def record(self, data: Dataset, masked: bool) -> Record:
        raise OptionError("a dynamic model's data enter its simulation: use data_vector()")

    def _prediction_expression(self, n_samples: int, theta, p, masked: bool) -> tuple:
        T, U, Z, d0 = dynamic_data_views(self.model, n_samples, masked, p)
        X = self.model.trajectory_symbols(theta, d0, T, U)
        return self.model.output_sequences(X, U, theta), Z

    def cost_expression(self, n_samples: int, theta, noise, p, masked: bool, noise_term: NoiseTerm, penalty) -> ca.MX:
        return dynamic_cost_expression(self.model, n_samples, theta, noise, p, masked, noise_term, penalty)

    def information_expression(self, n_samples: int, noise_term: NoiseTerm, theta: ca.MX) -> tuple[list, ca.MX]:
        model = self.model
        ny, N = model.n_outputs, n_samples
        T = ca.MX.sym("t", 1, N)
        U = ca.MX.sym("inputs", len(model.inputs), N)
        d0 = ca.MX.sym("x0_data", len(model.initial_from_data))
        R = noise_term.covariance_symbol(ny)
        w = ca.MX.sym("weights", 1, N)
        X = model.trajectory_symbols(theta, d0, T, U)
        Y = model.output_sequences(X, U, theta)
        J = ca.jacobian(ca.vec(Y), theta)  # sample-major rows: sample k's outputs together
        F = noise_term.stacked_information(J, R, w)
        named = [("t", T), ("inputs", U)] + ([("x0_data", d0)] if model.initial_from_data else [])
        return named + [("R", R), ("weights", w)], F

    def prefetch_hessian(self, n_samples: int) -> bool:
        """Compile the largest body of an RK4 model's exact Hessian in a background process
        (:func:`casest.backend.output_error.prefetch_second_order`) when the covariance will be
        compiled: it takes a second on big models, overlapped with stage 1 and stage 2.

        Parameters
        ----------
        n_samples : int

        Returns
        -------
        bool
            Whether a compile was started.
        """
        if not self.model_has_forward_sensitivities or not SolverSettings().resolved_jit(n_samples):
            return False
        # the flags cost_hessian compiles with: the covariance's SolverSettings() defaults
        return prefetch_second_order(self.model, sensitivity_flags(SolverSettings().jit_flags))

    def cost_hessian(self, n_samples: int, masked: bool, noise_term: NoiseTerm, threads=None, jit=False,
                     jit_flags=("-O2",)) -> ca.Function:
        model = self.model
        theta = ca.MX.sym("theta", model.n_parameters)
        rho = ca.MX.sym("rho", noise_term.block_size(model.n_outputs))
        p = ca.MX.sym("data", n_samples * (1 + len(model.inputs) + model.n_outputs * (2 if masked else 1))
                      + len(model.initial_from_data))
        w = ca.vertcat(theta, rho)
        if self.model_has_forward_sensitivities:
            sums = output_error_sums(model, n_samples, np.ones(model.n_parameters), masked, noise_term, jit,
                                     sensitivity_flags(jit_flags))
            J = sums.cost(w, p) * n_samples
            H = symmetric(sums.hessian(w, p)) * n_samples
        else:  # CasADi's AD through the integrator (or the delayed outputs)
            J = dynamic_cost_expression(model, n_samples, theta, rho, p, masked, noise_term, None)
            H, _ = ca.hessian(J, w)
        return ca.Function("J_hess", [theta, rho, p], [J, H], ["theta", "rho", "data"], ["J", "H"])

    def ml_sums(self, n_samples: int, scale, threads, jit, jit_flags, masked: bool, noise_term: NoiseTerm):
        raise OptionError("the per-sample sums treat the signals as data; a dynamic model's states depend on theta")

    def cost_sums(self, n_samples: int, masked: bool, noise_term: NoiseTerm, bound: bool) -> tuple:
        # the output model's sums on the simulated states (stage 2 differentiates the simulation instead)
        scale = np.ones(self.model.n_parameters)
        return ml_sums(self.cost_model, n_samples, scale, masked=masked, noise=noise_term, bound=bound), scale
