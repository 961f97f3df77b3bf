"""The measurement-model interface: what the stages need of a model, for both kinds.

A static :class:`casest.Model` and a :class:`casest.DynamicModel` differ in how their
outputs are obtained (a function of the measured signals, or of states simulated from
theta), so in how predictions, Jacobians, the data vector and the ML cost's CasADi graph
are built. :func:`measurement_of` wraps either in a :class:`Measurement` with one set of
methods; the Problem, stage 1, stage 2 and the embedding call those methods and never test
the model's type. It is the one place that does.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings
from ..backend.sensitivities import output_sensitivities
from ..backend.output_error import (dynamic_cost_expression, dynamic_data_views, output_error_sums, prediction_model,
                                    prefetch_second_order, sensitivity_flags)
from ..backend.penalty import GaussianPenalty
from ..backend.sums import (
    Record,
    data_outside_graph,
    map_sum,
    ml_sums,
    per_sample_cost,
    prediction_and_jacobian,
    residual_jacobian,
    symmetric,
)
from ..data.dataset import Dataset
from ..models import Model, OptionError
from ..models.dynamic import DynamicModel
from .experiments import stack_dynamic_experiments, stack_experiments


__all__ = ["Measurement", "StaticMeasurement", "DynamicMeasurement", "measurement_of", "ml_cost_expression",
           "data_vector", "data_symbols", "sum_data_symbols"]


class Measurement:
    """The stages' view of a model (base of :class:`StaticMeasurement` and :class:`DynamicMeasurement`).

    Attributes
    ----------
    model : Model or DynamicModel
    simulated : bool
        The outputs go through states simulated from theta (output error): stage 2 solves
        all parameters together (no variable projection), and long records keep their data
        in the graph.
    """

    simulated = False

    def __init__(self, model):
        self.model = model

    @property
    def through_states(self) -> tuple:
        """Parameters that act on the outputs through the states (the rhs or an initial state):
        never linear (xi1). None for a static model."""
        return ()

    @property
    def output_model(self) -> Model:
        """The static model of the output equation (signals: the states, then the inputs, for
        a dynamic model)."""
        return self.model

    def check_data(self, data: Dataset) -> None:
        """Raise a :class:`casest.DataError` if ``data`` do not fit the model.

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        None
        """
        data.check_model(self.model)

    def prefetch_hessian(self, n_samples: int) -> bool:
        """Start compiling, in the background, what the exact cost Hessian of N samples will need
        (nothing for a static model: its sums compile in a fraction of a second).

        Parameters
        ----------
        n_samples : int

        Returns
        -------
        bool
            Whether a compile was started.
        """
        return False

    def residual_expression(self, n_samples: int, theta, p, masked: bool) -> tuple:
        """The residuals at ``theta`` as CasADi expressions of the data vector ``p``.

        Returns
        -------
        residuals : casadi.MX, shape (n_outputs, N)
            ``z - h``, 0 where an output was not measured.
        outputs : casadi.MX, shape (n_outputs, N)
            z, 0 where not measured.
        counts : casadi.MX, shape (n_outputs, 1)
            The number of measurements N_j of each output.

        Parameters
        ----------
        n_samples : int
        theta : casadi.MX, shape (n_parameters, 1)
        p : casadi.MX
            The data vector.
        masked : bool
        """
        predictions, Z = self._prediction_expression(n_samples, theta, p, masked)
        ny = self.model.n_outputs
        if not masked:
            return Z - predictions, Z, ca.DM.ones(ny) * n_samples
        z, mask = Z[:ny, :], Z[ny:, :]
        return (z - predictions) * mask, z, ca.sum2(mask)

    def _outputs_from(self, Z: np.ndarray, masked: bool) -> np.ndarray:
        """Outputs (N, n_outputs) from the data vector's block, NaN where the mask says not measured."""
        ny = self.model.n_outputs
        return np.where(Z[:, ny:] > 0, Z[:, :ny], np.nan) if masked else Z

    def outputs_of(self, data: Dataset, masked: bool) -> np.ndarray:
        """The outputs as they enter the data vector, shape (N, n_outputs), or (N, 2 n_outputs)
        with ``masked``: z with 0 where not measured, then the mask.

        Parameters
        ----------
        data : Dataset
        masked : bool

        Returns
        -------
        ndarray
        """
        return np.hstack([data.filled_outputs(), data.output_mask()]) if masked else data.outputs


class StaticMeasurement(Measurement):
    """A static :class:`casest.Model`: ``z_k = h(x_k, theta) + v_k`` with measured signals x_k.

    Parameters
    ----------
    model : Model
    """

    @property
    def controlled_names(self) -> tuple:
        """The signals an experiment designer chooses: all of a static model's signals."""
        return tuple(self.model.signal_names)

    def controlled_history(self, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        """Their values, shape (n, N), and the samples' positions (a static model: the sample index).

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        history : ndarray, shape (n, N)
        positions : ndarray, shape (N,)
        """
        return data.signals.T.copy(), np.arange(data.n_samples, dtype=float)

    def information_arguments(self, history, times, data: Dataset) -> dict:
        """The data arguments of :func:`casest.design.information_function` for a signal history.

        Parameters
        ----------
        history : ndarray, shape (n, N)
            The controlled signals (:meth:`controlled_history`).
        times : ndarray, shape (N,)
        data : Dataset

        Returns
        -------
        dict of str to ndarray
        """
        return {"signals": history}

    def stack_experiments(self, experiments, separate_noise: bool) -> tuple:
        """Several experiments sharing the parameters as one model and data set
        (:func:`casest.experiments.stack_experiments`).

        Parameters
        ----------
        experiments : mapping of str to Dataset
        separate_noise : bool
            One R per experiment.

        Returns
        -------
        model : Model or DynamicModel
        data : Dataset
        """
        return stack_experiments(self.model, experiments, separate_noise)

    def predict(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        """Noise-free outputs at the data's samples, shape (N, n_outputs).

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset

        Returns
        -------
        ndarray, shape (N, n_outputs)
        """
        return self.model.predict(theta, data.signals)

    def signals_at(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        """The per-sample inputs of :attr:`cost_model`, shape (N, n_signals): the data's signals.

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset

        Returns
        -------
        ndarray
        """
        return data.signals

    @property
    def cost_model(self) -> Model:
        """The static model whose per-sample sums, fed :meth:`signals_at`, give the cost: the output equation."""
        return self.output_model

    def prediction_and_jacobian(self, theta: np.ndarray, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        """h, shape (N * n_outputs,), and dh/dtheta, shape (N * n_outputs, n_parameters), sample-major.

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset

        Returns
        -------
        h : ndarray, shape (N n_outputs,)
        J : ndarray, shape (N n_outputs, n_parameters)
        """
        return prediction_and_jacobian(self.model, data.signals, theta)

    def jacobian(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        """dh/dtheta at every sample, shape (N * n_outputs, n_parameters), sample-major.

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset

        Returns
        -------
        ndarray, shape (N n_outputs, n_parameters)
        """
        return residual_jacobian(self.model, data, theta)

    def data_vector(self, data: Dataset, masked: bool) -> np.ndarray:
        """The NLP parameter ``[vec(X); vec(Z)]`` (sample by sample; ``masked``: Z carries the mask).

        Parameters
        ----------
        data : Dataset
        masked : bool

        Returns
        -------
        ndarray
        """
        return np.concatenate([data.signals.reshape(-1), self.outputs_of(data, masked).reshape(-1)])

    def dataset_from_vector(self, p, n_samples: int, masked: bool) -> Dataset:
        """Inverse of :meth:`data_vector`: the data set of a data vector.

        Parameters
        ----------
        p : array_like
            A data vector (:meth:`data_vector`).
        n_samples : int
        masked : bool

        Returns
        -------
        Dataset
        """
        p = np.asarray(p, dtype=float).reshape(-1)
        ns, nz = self.model.n_signals, self.model.n_outputs * (2 if masked else 1)
        X, Z = p[:ns * n_samples].reshape(n_samples, ns), p[ns * n_samples:].reshape(n_samples, nz)
        return Dataset.from_arrays(self.model, X, self._outputs_from(Z, masked), missing="allow" if masked else "error")

    def data_outside_graph(self, n_samples: int) -> bool:
        """Long records keep their data outside the CasADi graph (:func:`casest.sums.data_outside_graph`).

        Parameters
        ----------
        n_samples : int

        Returns
        -------
        bool
        """
        return data_outside_graph(n_samples)

    def record(self, data: Dataset, masked: bool) -> Record:
        """The data as a :class:`casest.sums.Record` of (X, Z) for the bound sums.

        Parameters
        ----------
        data : Dataset
        masked : bool

        Returns
        -------
        Record
        """
        return Record(data.signals, self.outputs_of(data, masked))

    def _prediction_expression(self, n_samples: int, theta, p, masked: bool) -> tuple:
        X, Z = _data_views_of(self.model, n_samples, masked, p)
        return self.model.function.map(n_samples)(X, theta), Z

    def cost_expression(self, n_samples: int, theta, noise, p, masked: bool, full_noise: bool, penalty) -> ca.MX:
        """J of paper Eq. 6 as a CasADi expression (:func:`ml_cost_expression`).

        Parameters
        ----------
        n_samples : int
        theta : casadi.MX, shape (n_parameters, 1)
        noise : casadi.MX
            The noise block (``ln R`` or the log-Cholesky vector).
        p : casadi.MX
            The data vector.
        masked, full_noise : bool
        penalty : GaussianPenalty or None

        Returns
        -------
        casadi.MX
        """
        return ml_cost_expression(self.model, n_samples, theta, noise, p, masked, full_noise, penalty)

    def information_expression(self, n_samples: int, full_noise: bool, theta: ca.MX) -> tuple[list, ca.MX]:
        """The named inputs (signals, R, weights) and the Fisher information ``sum_k w_k J_k' R^-1 J_k``
        over N samples as an MX expression of them and ``theta`` (:func:`casest.design.information_function`).

        Parameters
        ----------
        n_samples : int
        full_noise : bool
        theta : casadi.MX, shape (n_parameters, 1)

        Returns
        -------
        inputs : list of casadi.MX
        information : casadi.MX, shape (n_parameters, n_parameters)
        """
        model = self.model
        n, ny = model.n_parameters, model.n_outputs
        J = ca.jacobian(model.h, model.theta)  # ny x n
        weight = ca.SX.sym("weight")
        Rinv = ca.SX.sym("Rinv", ny, ny) if full_noise else ca.SX.sym("Rinv", ny)
        WJ = ca.mtimes(Rinv, J) if full_noise else J * ca.repmat(Rinv, 1, n)
        per_sample = ca.Function("information_i", [model.x, weight, model.theta, Rinv],
                                 [weight * ca.mtimes(J.T, WJ)], ["x", "weight", "theta", "Rinv"], ["F"])
        X = ca.MX.sym("signals", model.n_signals, n_samples)
        w = ca.MX.sym("weights", 1, n_samples)
        R = ca.MX.sym("R", ny, ny) if full_noise else ca.MX.sym("R", ny)
        F = map_sum(per_sample, n_samples, 1, "information_sum")(X, w, theta, ca.inv(R) if full_noise else 1 / R)
        return [("signals", X), ("R", R), ("weights", w)], F

    def cost_hessian(self, n_samples: int, masked: bool, full_noise: bool, n_noise: int, threads=None, jit=False,
                     jit_flags=("-O2",)) -> ca.Function:
        """``(theta, noise vector, data) -> (J, H)`` from the per-sample sums (see :meth:`Problem.cost_hessian`).

        Parameters
        ----------
        n_samples : int
        masked, full_noise : bool
        n_noise : int
            Length of the noise block.
        threads : int, optional
        jit : bool
        jit_flags : tuple of str

        Returns
        -------
        casadi.Function
        """
        # the sums stage 2 compiled (same scale, threads and flags), so no second compile:
        # with w = [theta / scale; rho], H_theta = T H_w T, T = diag(1 / scale, 1)
        scale = self.model.scales
        sums = ml_sums(self.model, n_samples, scale, threads, jit, jit_flags, masked, full_noise,
                       bound=data_outside_graph(n_samples))
        p, data = sum_data_symbols(self.model, n_samples, masked)
        theta = ca.MX.sym("theta", self.model.n_parameters)
        rho = ca.MX.sym("rho", n_noise)
        w = ca.vertcat(theta / ca.DM(scale), rho)
        T = ca.DM(np.diag(np.concatenate([1.0 / scale, np.ones(n_noise)])))
        J = sums.cost(w, *data) * n_samples
        H = T @ symmetric(sums.hessian(w, *data)) @ T * n_samples
        return ca.Function("J_hess", [theta, rho, p], [J, H], ["theta", "rho", "data"], ["J", "H"])

    def ml_sums(self, n_samples: int, scale, threads, jit, jit_flags, masked: bool, full_noise: bool):
        """The compiled per-sample sums of J/N (:class:`casest.sums.MLSums`).

        Parameters
        ----------
        n_samples : int
        scale : array_like, shape (n_parameters,)
        threads : int or None
        jit : bool
        jit_flags : tuple of str
        masked, full_noise : bool

        Returns
        -------
        MLSums
        """
        return ml_sums(self.model, n_samples, scale, threads, jit, jit_flags, masked, full_noise)


class DynamicMeasurement(Measurement):
    """A :class:`casest.DynamicModel`: outputs of states simulated from theta (output error).

    Parameters
    ----------
    model : DynamicModel
    """

    simulated = True

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
        """The inputs an experiment designer chooses (not the time column)."""
        return tuple(u.name for u in self.model.inputs)

    def controlled_history(self, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        """The inputs, shape (n_inputs, N), and the sample times (s).

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        history : ndarray, shape (n, N)
        positions : ndarray, shape (N,)
        """
        return data.signals[:, 1:].T.copy(), data.signals[:, 0]

    def information_arguments(self, history, times, data: Dataset) -> dict:
        """The data arguments of :func:`casest.design.information_function` for a signal history.

        Parameters
        ----------
        history : ndarray, shape (n, N)
            The controlled signals (:meth:`controlled_history`).
        times : ndarray, shape (N,)
        data : Dataset

        Returns
        -------
        dict of str to ndarray
        """
        args = {"t": ca.DM(times).T, "inputs": history}
        if self.model.initial_from_data:
            args["x0_data"] = ca.DM(self.model.initial_values(data))
        return args

    def stack_experiments(self, experiments, separate_noise: bool) -> tuple:
        """Several manoeuvres, each with its own initial state, as one record whose simulation
        restarts at each one (:func:`casest.experiments.stack_dynamic_experiments`).

        Parameters
        ----------
        experiments : mapping of str to Dataset
        separate_noise : bool
            One R per experiment.

        Returns
        -------
        model : Model or DynamicModel
        data : Dataset
        """
        return stack_dynamic_experiments(self.model, experiments, separate_noise)

    def check_data(self, data: Dataset) -> None:
        self.model.check_data(data)

    def predict(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        """Noise-free outputs at the data's samples (simulated), shape (N, n_outputs).

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset

        Returns
        -------
        ndarray, shape (N, n_outputs)
        """
        return self.model.predict_data(theta, data)

    def signals_at(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        """The per-sample inputs of :attr:`cost_model`: the states simulated at theta beside the inputs,
        shape (N, n_states + n_inputs); with output delays the delayed predictions, shape (N, n_outputs).

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset

        Returns
        -------
        ndarray
        """
        states, outputs = self.model.simulate(theta, data)
        return outputs if self.model.output_delays else np.hstack([states, data.signals[:, 1:]])

    @property
    def cost_model(self) -> Model:
        """The output equation, or with output delays the identity on the delayed predictions
        (:func:`casest.backend.output_error.prediction_model`)."""
        return prediction_model(self.model) if self.model.output_delays else self.model.output_model

    def prediction_and_jacobian(self, theta: np.ndarray, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        """h and dh/dtheta through the states, shapes (N * n_outputs,) and (N * n_outputs, n_parameters):
        first-order forward sensitivities in one compiled pass for RK4 models
        (:class:`casest.backend.sensitivities.OutputSensitivities`), CasADi's AD through the
        integrator otherwise.

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset

        Returns
        -------
        h : ndarray, shape (N n_outputs,)
        J : ndarray, shape (N n_outputs, n_parameters)
        """
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
        """dh/dtheta through the states at every sample, sample-major.

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset

        Returns
        -------
        ndarray, shape (N n_outputs, n_parameters)
        """
        return self.prediction_and_jacobian(theta, data)[1]

    def data_vector(self, data: Dataset, masked: bool) -> np.ndarray:
        """``[t; vec(U); vec(Z); x0_data]``: times, inputs, outputs (``masked``: with the mask)
        and the initial values taken from the data.

        Parameters
        ----------
        data : Dataset
        masked : bool

        Returns
        -------
        ndarray
        """
        return np.concatenate([data.signals[:, 0], data.signals[:, 1:].reshape(-1),
                               self.outputs_of(data, masked).reshape(-1), self.model.initial_values(data)])

    def dataset_from_vector(self, p, n_samples: int, masked: bool) -> Dataset:
        """Inverse of :meth:`data_vector`: times, inputs, outputs and the initial values from data.

        Parameters
        ----------
        p : array_like
            A data vector (:meth:`data_vector`).
        n_samples : int
        masked : bool

        Returns
        -------
        Dataset
        """
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
        """Never: the data enter the simulation's graph.

        Parameters
        ----------
        n_samples : int

        Returns
        -------
        bool
        """
        return False

    def record(self, data: Dataset, masked: bool) -> Record:
        """Not available: a dynamic model's data enter the simulation's graph.

        Parameters
        ----------
        data : Dataset
        masked : bool

        Returns
        -------
        Record
            Never.

        Raises
        ------
        OptionError
            Always: use :meth:`data_vector`.
        """
        raise OptionError("a dynamic model's data enter its simulation: use data_vector()")

    def _prediction_expression(self, n_samples: int, theta, p, masked: bool) -> tuple:
        T, U, Z, d0 = dynamic_data_views(self.model, n_samples, masked, p)
        X = self.model.trajectory_symbols(theta, d0, T, U)
        return self.model.output_sequences(X, U, theta), Z

    def cost_expression(self, n_samples: int, theta, noise, p, masked: bool, full_noise: bool, penalty) -> ca.MX:
        """Output-error J through the simulation (:func:`casest.output_error.dynamic_cost_expression`).

        Parameters
        ----------
        n_samples : int
        theta : casadi.MX, shape (n_parameters, 1)
        noise : casadi.MX
            The noise block (``ln R`` or the log-Cholesky vector).
        p : casadi.MX
            The data vector.
        masked, full_noise : bool
        penalty : GaussianPenalty or None

        Returns
        -------
        casadi.MX
        """
        return dynamic_cost_expression(self.model, n_samples, theta, noise, p, masked, full_noise, penalty)

    def information_expression(self, n_samples: int, full_noise: bool, theta: ca.MX) -> tuple[list, ca.MX]:
        """The named inputs (times, inputs, initial values from data, R, weights) and the Fisher
        information through the simulation (sensitivities by CasADi's AD of the trajectory).

        Parameters
        ----------
        n_samples : int
        full_noise : bool
        theta : casadi.MX, shape (n_parameters, 1)

        Returns
        -------
        inputs : list of casadi.MX
        information : casadi.MX, shape (n_parameters, n_parameters)
        """
        model = self.model
        n, ny, N = model.n_parameters, model.n_outputs, n_samples
        T = ca.MX.sym("t", 1, N)
        U = ca.MX.sym("inputs", len(model.inputs), N)
        d0 = ca.MX.sym("x0_data", len(model.initial_from_data))
        R = ca.MX.sym("R", ny, ny) if full_noise else ca.MX.sym("R", ny)
        w = ca.MX.sym("weights", 1, N)
        X = model.trajectory_symbols(theta, d0, T, U)
        Y = model.output_sequences(X, U, theta)
        J = ca.jacobian(ca.vec(Y), theta)  # sample-major rows: sample k's outputs together
        if full_noise:
            F = ca.mtimes(J.T, ca.mtimes(ca.kron(ca.diag(ca.vec(w)), ca.inv(R)), J))
        else:
            s = ca.vec(ca.repmat(1 / R, 1, N) * ca.repmat(w, ny, 1))
            F = ca.mtimes(J.T, J * ca.repmat(s, 1, n))
        named = [("t", T), ("inputs", U)] + ([("x0_data", d0)] if model.initial_from_data else [])
        return named + [("R", R), ("weights", w)], F

    def prefetch_hessian(self, n_samples: int) -> bool:
        """Compile the second-order direction function of an RK4 model in a background process
        (:func:`casest.backend.output_error.prefetch_second_order`) when the covariance will be
        compiled: it takes seconds on big models, overlapped with stage 1 and stage 2.

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

    def cost_hessian(self, n_samples: int, masked: bool, full_noise: bool, n_noise: int, threads=None, jit=False,
                     jit_flags=("-O2",)) -> ca.Function:
        """``(theta, noise vector, data) -> (J, H)``: forward sensitivities for RK4 models,
        CasADi's exact Hessian through the integrator otherwise.

        Parameters
        ----------
        n_samples : int
        masked, full_noise : bool
        n_noise : int
            Length of the noise block.
        threads : int, optional
        jit : bool
        jit_flags : tuple of str

        Returns
        -------
        casadi.Function
        """
        model = self.model
        theta = ca.MX.sym("theta", model.n_parameters)
        rho = ca.MX.sym("rho", n_noise)
        p = ca.MX.sym("data", n_samples * (1 + len(model.inputs) + model.n_outputs * (2 if masked else 1))
                      + len(model.initial_from_data))
        w = ca.vertcat(theta, rho)
        if self.model_has_forward_sensitivities:
            sums = output_error_sums(model, n_samples, np.ones(model.n_parameters), masked, full_noise, jit,
                                     sensitivity_flags(jit_flags))
            J = sums.cost(w, p) * n_samples
            H = symmetric(sums.hessian(w, p)) * n_samples
        else:  # CasADi's AD through the integrator (or the delayed outputs)
            J = dynamic_cost_expression(model, n_samples, theta, rho, p, masked, full_noise, None)
            H, _ = ca.hessian(J, w)
        return ca.Function("J_hess", [theta, rho, p], [J, H], ["theta", "rho", "data"], ["J", "H"])

    def ml_sums(self, n_samples: int, scale, threads, jit, jit_flags, masked: bool, full_noise: bool):
        """Not available: a dynamic model's derivatives go through the simulation.

        Parameters
        ----------
        n_samples : int
        scale : array_like, shape (n_parameters,)
        threads : int or None
        jit : bool
        jit_flags : tuple of str
        masked, full_noise : bool

        Returns
        -------
        MLSums
            Never.

        Raises
        ------
        OptionError
            Always: use :meth:`cost_expression`.
        """
        raise OptionError("the per-sample sums treat the signals as data; a dynamic model's states depend on theta")


def measurement_of(model) -> Measurement:
    """The :class:`Measurement` of a model: the one place that tells the kinds apart.

    Parameters
    ----------
    model : Model or DynamicModel

    Returns
    -------
    Measurement
        A :class:`StaticMeasurement` or :class:`DynamicMeasurement`.

    Raises
    ------
    OptionError
        Anything else.
    """
    if isinstance(model, DynamicModel):
        return DynamicMeasurement(model)
    if isinstance(model, Model):
        return StaticMeasurement(model)
    raise OptionError(f"a casest.Model or casest.DynamicModel is needed, got {type(model).__name__}")


def ml_cost_expression(model: Model, n_samples: int, theta, noise, p, masked: bool = False,
                       full_noise: bool = False, penalty: tuple | None = None) -> ca.MX:
    """J of paper Eq. 6 as a CasADi expression, for graphs that CasADi differentiates.

    Parameters
    ----------
    model : Model
    n_samples : int
        N.
    theta : casadi.MX, shape (n_parameters, 1)
        Physical parameters.
    noise : casadi.MX
        ``ln R`` (n_outputs), or the log-Cholesky vector of a full R (``full_noise``).
    p : casadi.MX
        The data vector (:func:`data_vector`; with ``masked`` it carries the mask).
    penalty : tuple of (ndarray, ndarray), optional
        Means and precisions of Gaussian priors added as penalties.

    Returns
    -------
    casadi.MX
        The per-sample cost of :mod:`casest.sums` mapped over the samples and summed
        (a plain map, whose derivatives CasADi builds quickly), plus the penalty.
    """
    X, Z = _data_views_of(model, n_samples, masked, p)
    f_i = per_sample_cost(model, masked, full_noise)
    J = ca.sum2(f_i.map(n_samples)(X, Z, ca.vertcat(theta, noise)))
    penalty = GaussianPenalty.coerce(penalty)
    return J if penalty is None else J + penalty.expression(theta)



def data_vector(data: Dataset) -> np.ndarray:
    """The NLP parameter vector ``p = [vec(X); vec(Z)]`` of a data set (see :meth:`Problem.data_vector`).

    Parameters
    ----------
    data : Dataset

    Returns
    -------
    ndarray, shape (N (n_signals + n_outputs),)
        Column-major signals then outputs (with the mask rows when outputs are missing).
    """
    if data.has_missing:
        z = np.hstack([data.filled_outputs(), data.output_mask()])
        return np.concatenate([data.signals.reshape(-1), z.reshape(-1)])
    return np.concatenate([data.signals.reshape(-1), data.outputs.reshape(-1)])


def _data_views_of(model: Model, n_samples: int, masked: bool, p: ca.MX) -> tuple[ca.MX, ca.MX]:
    ns, ny, N = model.n_signals, model.n_outputs * (2 if masked else 1), n_samples
    # vertsplit keeps only offsets; p[a:b] would store N-long index vectors
    signals, outputs = ca.vertsplit(p, [0, ns * N, (ns + ny) * N])
    return ca.reshape(signals, ns, N), ca.reshape(outputs, ny, N)


def sum_data_symbols(model: Model, n_samples: int, masked: bool = False) -> tuple[ca.MX, list]:
    """The data parameter of graphs built on the ML sums, and the sums' data arguments.

    Parameters
    ----------
    model : Model
    n_samples : int
        N.
    masked : bool
        The outputs carry an observation mask.

    Returns
    -------
    parameter : casadi.MX
        The symbol the NLP takes as its data parameter (its value: :meth:`Problem.data_argument`).
    arguments : list of casadi.MX
        ``[record]`` for long records (:func:`casest.backend.data_outside_graph`), else ``[X, Z]``
        (:func:`data_symbols`).
    """
    if data_outside_graph(n_samples):
        record = ca.MX.sym("record")
        return record, [record]
    p, X, Z = data_symbols(model, n_samples, masked)
    return p, [X, Z]


def data_symbols(model: Model, n_samples: int, masked: bool = False) -> tuple[ca.MX, ca.MX, ca.MX]:
    """The NLP parameter ``p = [vec(X); vec(Z)]`` and its views.

    Parameters
    ----------
    model : Model
    n_samples : int
        N.
    masked : bool
        Z is ``[z; m]`` (2 n_y x N), m = 1 where an output was measured, 0 where not.

    Returns
    -------
    p : casadi.MX
    X : casadi.MX, shape (n_signals, N)
    Z : casadi.MX, shape (n_outputs, N) or (2 n_outputs, N)
    """
    p = ca.MX.sym("data", (model.n_signals + model.n_outputs * (2 if masked else 1)) * n_samples)
    X, Z = _data_views_of(model, n_samples, masked, p)
    return p, X, Z
