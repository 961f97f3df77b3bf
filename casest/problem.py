"""The estimation problem as one object: model, experiments, noise model, priors, fixed parameters.

A :class:`Problem` resolves what the user declared (one or several experiments, a noise
model, Gaussian priors as penalties, parameters held fixed, missing outputs) into the one
model and data set that every stage works on, and owns the one implementation of the
residuals, of the ML cost of paper Eq. 6 with its ln|R| terms (numeric values come from
the same per-sample CasADi functions whose exact derivatives stage 2 and the covariance
use, :mod:`casest.sums`), of the residual Jacobian and of the data vector. Stage 1
(:func:`casest.sweep`), stage 2 (:func:`casest.solve_stage2`), the covariance
(:func:`casest.parameter_uncertainty`), the embedding API, the baselines and the
Monte-Carlo code all take a Problem where they take a model and data.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Mapping

import casadi as ca
import numpy as np

from .data import DataError, Dataset
from .dynamic import DynamicModel
from .experiments import stack_experiments
from .model import Model, ModelError, OptionError
from .noise import (  # noqa: F401  (cholesky_vector, covariance_of: their old import path)
    DiagonalNoise,
    NoiseModel,
    cholesky_vector,
    covariance_of,
    n_cholesky,
)
from .numerics import StructureCache, compile_function, evaluate
from .sums import Record, data_outside_graph, map_sum, ml_sums, per_sample_cost, residual_jacobian, symmetric

__all__ = ["Problem", "as_problem", "ml_cost", "concentrated_cost", "ml_cost_expression", "data_symbols", "sum_data_symbols",
           "data_vector",
           "cholesky_vector",
           "covariance_of", "NOISE_KINDS"]

#: The labels of the noise models (``NoiseModel.kind``): estimated diagonal (paper Eq. 6), known, estimated full.
NOISE_KINDS = ("diagonal", "known", "full")


class Problem:
    """The estimation problem every stage consumes.

    Parameters
    ----------
    model : Model
        The declared measurement model.
    data : Dataset, or sequence / mapping of Dataset
        The (stage-2) data, N samples; several data sets are experiments that share the
        parameters (see ``separate_noise``), stacked sample after sample.
    stage1_data : Dataset, optional
        Data for the stage-1 sweep (default ``data``); not with separate noise per experiment.
    noise : NoiseModel, optional
        :class:`casest.DiagonalNoise` (the default: R unknown and diagonal, estimated with
        theta, paper Eq. 6), :class:`casest.KnownNoise` or :class:`casest.CorrelatedNoise`.
    fixed : mapping of str to float, optional
        Parameters held at these values (with those declared ``Parameter(fixed=True)``, held
        at their nominal values); they are substituted into the model and drop out of
        every stage.
    prior_penalty : bool
        MAP: the parameters' Gaussian priors enter the cost as ``(theta - mean)^2 / (2 std^2)``.
    separate_noise : bool
        With several experiments: one R per experiment (outputs ``output@experiment``), or
        one R for all.

    Attributes
    ----------
    model : Model
        The model estimated: experiments expanded, fixed parameters substituted.
    data : Dataset
        The stacked data for ``model`` (missing outputs allowed and masked).
    stage1_data : Dataset or None
    declared_model : Model
        The model as given.
    full_model : Model
        ``model`` before the fixed parameters were substituted (all parameters).
    held : dict of str to float
        The fixed parameters and their values.
    experiments : tuple of str
        The experiments' names (empty for a single data set).
    noise : NoiseModel
        The noise model (for several experiments with a known R per output: one std per
        output and experiment).
    noise_kind : {"diagonal", "known", "full"}
        ``noise.kind``, a label for reports.
    known_R : ndarray, shape (n_outputs,) or None
        The known noise variances.
    penalty : tuple of (ndarray, ndarray) or None
        ``(means, precisions)`` of the Gaussian priors used as penalties.
    separate_noise : bool
    """

    def __init__(self, model: Model, data, *, stage1_data: Dataset | None = None,
                 noise: NoiseModel | None = None, fixed: Mapping[str, float] | None = None,
                 prior_penalty: bool = False, separate_noise: bool = True):
        if not isinstance(model, (Model, DynamicModel)):
            raise OptionError(f"a Problem needs a casest.Model or casest.DynamicModel, got {type(model).__name__}")
        self.dynamic = isinstance(model, DynamicModel)
        if model.n_parameters == 0:
            raise ModelError(f"model {model.name!r} has no parameters to estimate; for its states use "
                             "casest.ExtendedKalmanFilter (or KalmanFilter) and rts_smoother")
        noise = DiagonalNoise() if noise is None else noise
        if not isinstance(noise, NoiseModel):
            raise OptionError("noise must be casest.DiagonalNoise(), casest.KnownNoise(...) or casest.CorrelatedNoise(), "
                              f"got {noise!r}")
        self.declared_model = model
        self.noise = noise
        self.separate_noise = bool(separate_noise)
        self.experiments: tuple = ()
        if isinstance(data, Dataset):
            full_model = model
        elif self.dynamic:
            raise OptionError("several experiments of a DynamicModel are not offered yet (each has its own initial "
                              "state and time axis): estimate one record at a time")
        else:  # several experiments sharing the parameters
            if stage1_data is not None and separate_noise:
                raise OptionError("with several experiments and separate noise, stage 1 runs on the experiments "
                                  "themselves; leave stage1_data out (or use separate_noise=False)")
            if noise.full and separate_noise:
                raise OptionError("a full unknown R per experiment is not offered: use separate_noise=False "
                                  "(--shared-noise; one full R for all experiments) or estimate the experiments "
                                  "one at a time")
            full_model, data, self.experiments = stack_experiments(model, data, separate_noise)
            if separate_noise:
                self.noise = noise.for_experiments(model.output_names, self.experiments)
        self.full_model = full_model
        held = {p.name: p.nominal for p in full_model.parameters if p.fixed}
        held.update({str(k): float(v) for k, v in dict(fixed or {}).items()})
        self.held = held
        self.model = full_model.with_fixed(held) if held else full_model
        data.check_model(self.model)
        if stage1_data is not None:
            stage1_data.check_model(self.model)
        if self.dynamic:
            for d in (data, stage1_data):
                if d is not None:
                    self.model.check_data(d)
        self.data = data
        self.stage1_data = stage1_data
        self.noise.bind(self.model)
        self.noise.check_data(data)
        self.known_R = self.noise.given_variances(self.model)
        self.prior_penalty = bool(prior_penalty)
        self.penalty = self.model.gaussian_prior_terms() if prior_penalty else None
        self._stage1 = None

    # ------------------------------------------------------------------ structure
    @property
    def n_samples(self) -> int:
        """N, the number of samples of the (stacked) data."""
        return self.data.n_samples

    @property
    def masked(self) -> bool:
        """Some outputs are missing: the data vector carries the observation mask."""
        return self.data.has_missing

    @property
    def noise_kind(self) -> str:
        """The noise model's label (``noise.kind``: "diagonal", "known" or "full"), for reports."""
        return self.noise.kind

    @property
    def full_noise(self) -> bool:
        """R is a full matrix (log-Cholesky block), the sums' ``full_noise``."""
        return self.noise.full

    @property
    def n_noise(self) -> int:
        """Length of the noise block of the decision vector (ln R_j, or the log-Cholesky vector)."""
        return self.noise.vector_size(self.model.n_outputs)

    def describe_noise(self) -> str:
        """One line for reports."""
        return self.noise.describe(self.model)

    def with_data(self, data, stage1_data: Dataset | None = None) -> "Problem":
        """The same problem (model, noise model, priors, fixed parameters) on other data."""
        noise = self.noise
        if self.experiments and self.separate_noise:
            noise = noise.for_declared_outputs(self.declared_model.output_names, self.experiments)
        return Problem(self.declared_model, data, stage1_data=stage1_data, noise=noise,
                       fixed={k: v for k, v in self.held.items()}, prior_penalty=self.prior_penalty,
                       separate_noise=self.separate_noise)

    def stage1_inputs(self) -> tuple[Model, Dataset, bool]:
        """Model and data the sweep works on, and whether they are weighted by the known noise.

        With known R the outputs and data are divided by the known std, so that Tr[R] of
        the sweep ranks candidates by the weighted residuals.
        """
        if self._stage1 is None:
            swept = self.stage1_data or self.data
            weights = self.noise.stage1_weights(self.model)
            if weights is None:
                self._stage1 = (self.model, swept, False)
            else:
                weighted = self.model.with_output_weights(weights)
                self._stage1 = (weighted, Dataset.from_arrays(
                    weighted, swept.signals, swept.outputs * weights,
                    missing="allow" if swept.has_missing else "error"), True)
        return self._stage1

    # ------------------------------------------------------------------ numeric values
    def vector(self, theta) -> np.ndarray:
        """Parameters of :attr:`model` as a vector, shape (n_parameters,).

        ``theta`` is a mapping (names of fixed parameters are ignored), a vector of the
        estimated parameters, or a vector of all declared parameters (the fixed entries
        are dropped).
        """
        if isinstance(theta, Mapping):
            return self.model.vector({k: v for k, v in theta.items() if k not in self.held})
        arr = np.asarray(theta, dtype=float).reshape(-1)
        if self.held and arr.size == self.full_model.n_parameters != self.model.n_parameters:
            keep = [i for i, n in enumerate(self.full_model.parameter_names) if n not in self.held]
            arr = arr[keep]
        return self.model.vector(arr)

    def residuals(self, theta) -> np.ndarray:
        """``z_k - h(x_k, theta)``, shape (N, n_outputs), NaN where an output was not measured."""
        return self.data.outputs - self.predict(theta)

    def predict(self, theta) -> np.ndarray:
        """Noise-free outputs at the data's samples, shape (N, n_outputs) (a dynamic model: simulated)."""
        if self.dynamic:
            return self.model.predict_data(self.vector(theta), self.data)
        return self.model.predict(self.vector(theta), self.data.signals)

    def _signals_at(self, theta) -> np.ndarray:
        """The per-sample inputs of the output equation, shape (N, n): the data's signals, or for a
        dynamic model the simulated states at theta beside the inputs."""
        if not self.dynamic:
            return self.data.signals
        states, _ = self.model.simulate(self.vector(theta), self.data)
        return np.hstack([states, self.data.signals[:, 1:]])

    @property
    def output_model(self) -> Model:
        """The static model of the output equation (the model itself, for a static model)."""
        return self.model.output_model if self.dynamic else self.model

    def jacobian(self, theta) -> np.ndarray:
        """d h / d theta at every sample, shape (N * n_outputs, n_parameters), sample-major;
        the rows of outputs not measured are zero."""
        if self.dynamic:  # through the states
            J = self.model.prediction_and_jacobian(self.data, self.vector(theta))[1]
        else:
            J = residual_jacobian(self.model, self.data, self.vector(theta))
        return J * self.data.output_mask().reshape(-1)[:, None] if self.masked else J

    def residual_mean_square(self, theta) -> np.ndarray:
        """Per-output mean square of the measured residuals, ``sum_k r_kj^2 / N_j``, shape (n_outputs,).

        The ML estimate of the diagonal R at theta.
        """
        resid = np.nan_to_num(self.residuals(theta))
        return np.sum(resid**2, axis=0) / self.data.observed_counts()

    def residual_covariance(self, theta) -> np.ndarray:
        """``r' r / N``, shape (n_outputs, n_outputs): the ML estimate of a full R at theta."""
        resid = np.nan_to_num(self.residuals(theta))
        return resid.T @ resid / self.n_samples

    def noise_vector(self, R) -> np.ndarray:
        """The noise block of the decision vector: ``ln R_j`` (R the diagonal, shape (n_outputs,)),
        or the log-Cholesky vector of a full R (shape (n_outputs, n_outputs))."""
        return self.noise.to_vector(R)

    def noise_of(self, vector) -> np.ndarray:
        """Inverse of :meth:`noise_vector`: the diagonal R, or the full R of a :class:`casest.CorrelatedNoise`."""
        return self.noise.from_vector(vector, self.model.n_outputs)

    def cost(self, theta, R=None) -> float:
        """J of paper Eq. 6 without constants, with each channel's own count N_j in ln R_j.

        Parameters
        ----------
        theta : array_like, shape (n_parameters,), or mapping
            Physical parameters.
        R : array_like, optional
            Diagonal of R, shape (n_outputs,), or a full R, shape (n_outputs, n_outputs)
            (unit of z squared). Default: the known R, or the R that minimises J at theta
            (:meth:`profile_cost`).

        Returns
        -------
        float
            ``1/2 sum_k r_k' R^-1 r_k + 1/2 sum_j N_j ln R_j`` (full R: ``N/2 ln|R|``), plus
            the prior penalty for MAP problems.
        """
        theta = self.vector(theta)
        if R is None:
            return self.profile_cost(theta)
        R = np.asarray(R, dtype=float)
        full = R.ndim == 2
        if full and self.masked:
            raise DataError("a full R needs complete data")
        outside = data_outside_graph(self.n_samples)
        sums = ml_sums(self.output_model, self.n_samples, np.ones(self.model.n_parameters),
                       masked=self.masked and not full, full_noise=full, bound=outside)
        rho = cholesky_vector(R) if full else np.log(R.reshape(-1))
        X, Z = self._data_views(full, theta)
        if outside:
            with Record(X.T, Z.T) as record:
                (value,) = evaluate(sums.cost, np.concatenate([theta, rho]), record.handle)
        else:
            (value,) = evaluate(sums.cost, np.concatenate([theta, rho]), X, Z)
        return float(value[0]) * self.n_samples + self.penalty_value(theta)

    def profile_cost(self, theta) -> float:
        """J at theta with R at its ML value there (known R: the known R), plus any prior penalty.

        The common yardstick for comparing estimates of different methods on the same data.
        """
        theta = self.vector(theta)
        return self.cost(theta, self.noise.profile(self, theta))

    def penalty_value(self, theta) -> float:
        """``sum P_i (theta_i - mu_i)^2 / 2`` of the priors used as penalties; 0 without them."""
        if self.penalty is None:
            return 0.0
        mean, precision = self.penalty
        return float(0.5 * np.sum(precision * (np.asarray(theta, dtype=float) - mean) ** 2))

    def start_point(self, theta0, floor: np.ndarray, R0=None) -> tuple[float, np.ndarray]:
        """Where stage 2 starts from ``theta0``: the cost J there and the noise R it starts with.

        R is the known R, else the given ``R0``, else the ML R at ``theta0`` (the residual
        mean square, held above ``floor``; a full R: the residual covariance plus the floor
        on its diagonal).

        Returns
        -------
        cost : float
        R : ndarray, shape (n_outputs,), or (n_outputs, n_outputs) for a full R
        """
        theta0 = self.vector(theta0)
        R = self.noise.start(self, theta0, floor, R0)
        return self.cost(theta0, R), R

    def data_vector(self) -> np.ndarray:
        """The NLP parameter ``p = [vec(X); vec(Z)]`` (column-major, sample by sample).

        With missing outputs Z is ``[z; m]`` per sample: z with 0 where not measured, m the mask.
        A dynamic model's is ``[t; vec(U); vec(Z); x0_data]`` (times, inputs, outputs and the
        initial values taken from the data).
        """
        if self.dynamic:
            d = self.data
            z = np.hstack([d.filled_outputs(), d.output_mask()]) if self.masked else d.outputs
            return np.concatenate([d.signals[:, 0], d.signals[:, 1:].reshape(-1), z.reshape(-1),
                                   self.model.initial_values(d)])
        return data_vector(self.data)

    @contextmanager
    def data_argument(self):
        """The data argument of :meth:`cost_hessian` (and of stage 2's NLP), valid inside the
        ``with`` block: a bound :meth:`record`'s handle for long records
        (:func:`casest.sums.data_outside_graph`), else :meth:`data_vector`."""
        if self.dynamic or not data_outside_graph(self.n_samples):
            yield self.data_vector()
            return
        with self.record() as record:
            yield np.array([record.handle])

    def record(self) -> Record:
        """The data of a static problem as a :class:`casest.sums.Record` of (X, Z), the data
        argument of the bound sums (stage 2, :meth:`cost_hessian`); bind it with ``with``."""
        if self.dynamic:
            raise OptionError("a dynamic model's data enter its simulation: use data_vector()")
        X, Z = self._data_views(self.full_noise)
        return Record(X.T, Z.T)

    def _data_views(self, full: bool = False, theta=None) -> tuple[np.ndarray, np.ndarray]:
        X = self._signals_at(theta).T if self.dynamic else self.data.signals.T
        if self.masked and not full:
            return X, np.vstack([self.data.filled_outputs().T, self.data.output_mask().T])
        return X, self.data.outputs.T

    # ------------------------------------------------------------------ symbolic parts
    def sums(self, scale=None, threads: int | None = None, jit: bool = False, jit_flags=("-O2",)):
        """The compiled per-sample sums of J/N, its gradient and Hessian (:class:`casest.sums.MLSums`)
        in ``w = [theta / scale; noise vector]``. Static models only: a dynamic model's states
        depend on theta, so its derivatives go through the simulation (:meth:`cost_expression`)."""
        if self.dynamic:
            raise OptionError("the per-sample sums treat the signals as data; a dynamic model's states depend on theta")
        return ml_sums(self.model, self.n_samples, scale, threads, jit, jit_flags, self.masked,
                       self.full_noise)

    def cost_hessian(self, threads: int | None = None, jit: bool = False, jit_flags=("-O2",)) -> ca.Function:
        """``(theta, noise vector, data) -> (J, H)``: Eq. 6 (without the prior penalty) and its exact
        Hessian in (physical theta, noise vector), from the per-sample sums (a dynamic model:
        CasADi's exact Hessian through the simulation).

        ``data``: a static problem's :meth:`data_argument` (a :meth:`record` handle for long
        records, else the data vector), a dynamic one's :meth:`data_vector`.
        """
        if self.dynamic:
            theta = ca.MX.sym("theta", self.model.n_parameters)
            rho = ca.MX.sym("rho", self.n_noise)
            p = ca.MX.sym("data", self.data_vector().size)
            w = ca.vertcat(theta, rho)
            if self.model.integrator == "rk4":  # forward sensitivities
                sums = output_error_sums(self.model, self.n_samples, np.ones(self.model.n_parameters), self.masked,
                                         self.full_noise, jit, jit_flags if jit_flags != ("-O2",) else ("-O1",))
                J = sums.cost(w, p) * self.n_samples
                H = symmetric(sums.hessian(w, p)) * self.n_samples
            else:  # CasADi's AD through the integrator
                J = dynamic_cost_expression(self.model, self.n_samples, theta, rho, p, self.masked,
                                            self.full_noise, None)
                H, _ = ca.hessian(J, w)
            return ca.Function("J_hess", [theta, rho, p], [J, H], ["theta", "rho", "data"], ["J", "H"])
        # the sums stage 2 compiled (same scale, threads and flags), so no second compile:
        # with w = [theta / scale; rho], H_theta = T H_w T, T = diag(1 / scale, 1)
        scale = self.model.scales
        sums = ml_sums(self.model, self.n_samples, scale, threads, jit, jit_flags, self.masked,
                       self.full_noise, bound=data_outside_graph(self.n_samples))
        p, data = sum_data_symbols(self.model, self.n_samples, self.masked)
        theta = ca.MX.sym("theta", self.model.n_parameters)
        rho = ca.MX.sym("rho", self.n_noise)
        w = ca.vertcat(theta / ca.DM(scale), rho)
        T = ca.DM(np.diag(np.concatenate([1.0 / scale, np.ones(self.n_noise)])))
        J = sums.cost(w, *data) * self.n_samples
        H = T @ symmetric(sums.hessian(w, *data)) @ T * self.n_samples
        return ca.Function("J_hess", [theta, rho, p], [J, H], ["theta", "rho", "data"], ["J", "H"])

    def cost_expression(self, theta: ca.MX, noise: ca.MX, p: ca.MX) -> ca.MX:
        """J (with the prior penalty) as a CasADi expression (see :func:`ml_cost_expression`;
        a dynamic model: :func:`dynamic_cost_expression`)."""
        if self.dynamic:
            return dynamic_cost_expression(self.model, self.n_samples, theta, noise, p, self.masked,
                                           self.full_noise, self.penalty)
        return ml_cost_expression(self.model, self.n_samples, theta, noise, p, self.masked,
                                  self.full_noise, self.penalty)


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
    if penalty is not None:
        mean, precision = (ca.DM(v) for v in penalty)
        J = J + 0.5 * ca.sum1(precision * (theta - mean) ** 2)
    return J


class OutputErrorSums:
    """Output-error J/N of a dynamic model, its gradient and exact Hessian, by forward sensitivities.

    The simulation carries the derivatives of the states with respect to the parameters of
    the dynamics (first order ``S = dx/dtheta_D`` for the gradient, and second order
    ``T = d2x/dtheta_D2`` for the Hessian): each interval's step is applied to the jet
    ``x + S d + d' T d / 2`` and differentiated symbolically (SX), one ``mapaccum`` over the
    samples. Each sample's cost (:func:`casest.sums.per_sample_cost` of the output equation)
    is differentiated the same way, with the jet of its states, and summed with a
    map-reduce. The result is the exact gradient and Hessian of the discretised cost, for
    RK4 models (a CVODES model uses CasADi's AD through the integrator). With ``jit`` the
    step and per-sample functions (small SX bodies) are compiled to C; the loops over the
    samples call them.

    Attributes
    ----------
    cost, gradient, hessian : casadi.Function
        ``(w, p) -> J/N``, ``(w, p) -> (J/N, dJ/dw / N)``, ``(w, p) -> triu(d2J/dw2) / N``
        with ``w = [theta / scale; noise vector]`` and ``p`` the data vector
        (:meth:`Problem.data_vector`).
    """

    def __init__(self, model: DynamicModel, n_samples: int, scale, masked: bool = False, full_noise: bool = False,
                 jit: bool = False, jit_flags=("-O1",)):
        N, n, ny, nu = n_samples, model.n_parameters, model.n_outputs, len(model.inputs)
        self.model, self.n_samples = model, N
        self._D = [i for i, name in enumerate(model.parameter_names) if name in model.dynamic_parameters]
        self._masked, self._full_noise = masked, full_noise
        self._jit, self._jit_flags = jit, tuple(jit_flags)
        n_noise = n_cholesky(ny) if full_noise else ny
        nz = 2 * ny if masked else ny
        p = ca.MX.sym("data", N + nu * N + nz * N + len(model.initial_from_data))
        Tm, Um, Zm, d0m = dynamic_data_views(model, N, masked, p)
        ws = ca.MX.sym("w", n + n_noise)
        scale_all = ca.DM(np.concatenate([np.asarray(scale, dtype=float), np.ones(n_noise)]))
        w_phys = ws * scale_all
        sums = []
        for order in (0, 1, 2):
            step, initial, per_sample = self._jet_functions(order)
            th = w_phys[:n]
            a0 = initial(th, d0m)
            if N > 1:
                T0, T1 = ca.horzsplit(Tm, [0, N - 1, N])[0], ca.horzsplit(Tm, [0, 1, N])[1]
                Ua, Ub = model.interval_inputs(Um)
                th_D = ca.vertcat(*[th[i] for i in self._D]) if self._D else ca.MX(0, 1)
                run = step.mapaccum(f"jet{order}_simulate", N - 1)
                A = ca.horzcat(a0, run(a0, Ua, Ub, T1 - T0, ca.repmat(th_D, 1, N - 1)))
            else:
                A = a0
            out = map_sum(per_sample, N, 1, f"oe{order}_sum")(ca.vertcat(A, Um), Zm, w_phys)
            sums.append(out if isinstance(out, (list, tuple)) else [out])
        (cost,), (value, grad), (hess,) = sums
        Ds = ca.diag(scale_all)
        grad = grad * scale_all
        hess = ca.triu(ca.mtimes(ca.mtimes(Ds, symmetric(hess)), Ds))
        self.cost = ca.Function("oe_cost", [ws, p], [cost / N], ["w", "p"], ["f"])
        self.gradient = ca.Function("oe_gradient", [ws, p], [value / N, grad / N], ["w", "p"], ["f", "g"])
        self.hessian = ca.Function("oe_hessian", [ws, p], [hess / N], ["w", "p"], ["H"])

    def _jet_functions(self, order: int) -> tuple:
        """The step, initial state and per-sample function with jets of ``order`` (0, 1 or 2)."""
        model, D = self.model, self._D
        n, nx, nu, ny = model.n_parameters, model.n_states, len(model.inputs), model.n_outputs
        nD = len(D) if order else 0
        n_noise = n_cholesky(ny) if self._full_noise else ny
        x, S = ca.SX.sym("x", nx), ca.SX.sym("S", nx, nD)
        T = ca.SX.sym("T", nx * nD * nD if order == 2 else 0)
        n_step_u = model.step_function.size1_in(1)  # 2 n_u for cubic interpolation
        uk, uk1, dt = ca.SX.sym("uk", n_step_u), ca.SX.sym("uk1", n_step_u), ca.SX.sym("dt")
        theta_D, d = ca.SX.sym("theta_D", len(D)), ca.SX.sym("d", nD)
        x_jet = _jet(x, S, T, d, nx, nD)
        rhs_pos = [D.index(i) for i in model.rhs_parameter_index]
        shifted = theta_D + d if nD else theta_D
        theta_rhs = ca.vertcat(*[shifted[k] for k in rhs_pos]) if rhs_pos else ca.SX(0, 1)
        x_next = model.step_function(x_jet, uk, uk1, dt, theta_rhs)
        aug = ca.vertcat(x, ca.vec(S), T)
        step = ca.Function(f"jet{order}_step", [aug, uk, uk1, dt, theta_D],
                           [ca.cse(_jet_coefficients(x_next, d, nx, nD, order))])
        theta, d0 = ca.SX.sym("theta", n), ca.SX.sym("x0_data", len(model.initial_from_data))
        shift = ca.SX.zeros(n)
        for k, i in enumerate(D[:nD]):
            shift[i] = d[k]
        initial = ca.Function(f"jet{order}_initial", [theta, d0],
                              [_jet_coefficients(model.initial_function(theta + shift, d0), d, nx, nD, order)])
        a_k, u_k = ca.SX.sym("aug", aug.numel()), ca.SX.sym("u", nu)
        z, w = ca.SX.sym("z", 2 * ny if self._masked else ny), ca.SX.sym("w", n + n_noise)
        f_i = per_sample_cost(model.output_model, self._masked, self._full_noise)
        names = ["s", "z", "w"]
        if order == 0:
            per_sample = ca.Function("oe0_i", [ca.vertcat(a_k, u_k), z, w], [f_i(ca.vertcat(a_k, u_k), z, w)], names,
                                     ["f"])
        else:
            delta = ca.SX.sym("delta", n + n_noise)
            xk, Sk = a_k[:nx], ca.reshape(a_k[nx:nx + nx * nD], nx, nD)
            Tk = a_k[nx + nx * nD:]
            states = _jet(xk, Sk, Tk, ca.vertcat(*[delta[i] for i in D]) if D else ca.SX(0, 1), nx, nD)
            f = f_i(ca.vertcat(states, u_k), z, w + delta)
            zero = ca.DM.zeros(n + n_noise)
            f0 = ca.substitute(f, delta, zero)
            if order == 1:
                g = ca.substitute(ca.gradient(f, delta), delta, zero)
                outputs, out_names = [f0, ca.cse(g)], ["f", "g"]
            else:
                outputs, out_names = [ca.cse(ca.substitute(ca.triu(ca.hessian(f, delta)[0]), delta, zero))], ["H"]
            per_sample = ca.Function(f"oe{order}_i", [ca.vertcat(a_k, u_k), z, w], outputs, names, out_names)
        if self._jit:  # the small SX bodies are compiled; the loops over samples call them
            step, per_sample = compile_function(step, self._jit_flags), compile_function(per_sample, self._jit_flags)
        return step, initial, per_sample


def _jet(x, S, T, d, nx: int, nD: int):
    """``x + S d + d' T_i d / 2`` per state (T stacked as nx blocks of nD x nD, or empty: first order)."""
    if nD == 0:
        return x
    out = x + ca.mtimes(S, d)
    if T.numel():
        quad = [ca.mtimes([d.T, ca.reshape(T[i * nD * nD:(i + 1) * nD * nD], nD, nD), d]) for i in range(nx)]
        out = out + 0.5 * ca.vertcat(*quad)
    return out


def _jet_coefficients(y, d, nx: int, nD: int, order: int):
    """``[y; vec(dy/dd); d2y_i/dd2 ...]`` at d = 0, up to ``order``: the jet of y in d."""
    if nD == 0 or order == 0:
        return ca.substitute(y, d, ca.DM.zeros(d.numel())) if d.numel() else y
    zero = ca.DM.zeros(nD)
    parts = [y, ca.vec(ca.jacobian(y, d))]
    if order == 2:
        parts += [ca.vec(ca.hessian(y[i], d)[0]) for i in range(nx)]
    return ca.substitute(ca.vertcat(*parts), d, zero)


_OE_SUMS = StructureCache()


def output_error_sums(model: DynamicModel, n_samples: int, scale=None, masked: bool = False,
                      full_noise: bool = False, jit: bool = False, jit_flags=("-O1",)) -> OutputErrorSums:
    """Cached :class:`OutputErrorSums` for (model, N, scale, masked, full noise, jit)."""
    scale = tuple(np.asarray(model.scales if scale is None else scale, dtype=float))
    key = (n_samples, scale, bool(masked), bool(full_noise), bool(jit), tuple(jit_flags))
    cache = _OE_SUMS.setdefault(model, {})
    if key not in cache:
        cache[key] = OutputErrorSums(model, n_samples, np.array(scale), masked, full_noise, jit, jit_flags)
    return cache[key]


def dynamic_data_views(model: DynamicModel, n_samples: int, masked: bool, p):
    """Views of a dynamic model's data vector ``[t; vec(U); vec(Z); x0_data]``: T (1 x N), U (n_u x N),
    Z (n_z x N; with ``masked`` [z; m]) and x0_data (offsets only, no N-long index vectors)."""
    N, nu = n_samples, len(model.inputs)
    nz = model.n_outputs * (2 if masked else 1)
    T, U, Z, d0 = ca.vertsplit(p, [0, N, N + nu * N, N + (nu + nz) * N, p.numel()])
    return ca.reshape(T, 1, N), ca.reshape(U, nu, N), ca.reshape(Z, nz, N), d0


def dynamic_cost_expression(model: DynamicModel, n_samples: int, theta, noise, p, masked: bool = False,
                            full_noise: bool = False, penalty: tuple | None = None) -> ca.MX:
    """Output-error J of a dynamic model as a CasADi expression (summary Sec. 5, Eq. 5.7 with
    deterministic states; paper Eq. 6 for the outputs).

    The states are simulated from theta (:meth:`DynamicModel.trajectory_symbols`) and the
    per-sample cost of :mod:`casest.sums` (the output equation's) is mapped over the
    samples. ``p`` is ``[t; vec(U); vec(Z); x0_data]`` (:meth:`Problem.data_vector`).
    """
    N = n_samples
    T, U, Z, d0 = dynamic_data_views(model, N, masked, p)
    X = model.trajectory_symbols(theta, d0, T, U)
    f_i = per_sample_cost(model.output_model, masked, full_noise)
    J = ca.sum2(f_i.map(N)(ca.vertcat(X, U), Z, ca.vertcat(theta, noise)))
    if penalty is not None:
        mean, precision = (ca.DM(v) for v in penalty)
        J = J + 0.5 * ca.sum1(precision * (theta - mean) ** 2)
    return J


def as_problem(model, data=None, **options) -> Problem:
    """``model`` itself if it is a :class:`Problem` (then ``data`` must be None or its data),
    else ``Problem(model, data, **options)``."""
    if isinstance(model, Problem):
        if data is not None and data is not model.data:
            return model.with_data(data)
        return model
    if data is None:
        raise OptionError("give the data: a Dataset, or several (experiments), or a casest.Problem")
    return Problem(model, data, **options)


def data_vector(data: Dataset) -> np.ndarray:
    """The NLP parameter vector ``p = [vec(X); vec(Z)]`` of a data set (see :meth:`Problem.data_vector`)."""
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
    """The data parameter of graphs built on the ML sums, and the sums' data arguments:
    ``(record, [record])`` for long records (:func:`casest.sums.data_outside_graph`), else
    ``(p, [X, Z])`` (:func:`data_symbols`). Its value is :meth:`Problem.data_argument`."""
    if data_outside_graph(n_samples):
        record = ca.MX.sym("record")
        return record, [record]
    p, X, Z = data_symbols(model, n_samples, masked)
    return p, [X, Z]


def data_symbols(model: Model, n_samples: int, masked: bool = False) -> tuple[ca.MX, ca.MX, ca.MX]:
    """The NLP parameter ``p = [vec(X); vec(Z)]`` and its views X (n_s x N), Z (n_y x N).

    ``masked``: Z is ``[z; m]`` (2 n_y x N), m = 1 where an output was measured, 0 where not.
    """
    p = ca.MX.sym("data", (model.n_signals + model.n_outputs * (2 if masked else 1)) * n_samples)
    X, Z = _data_views_of(model, n_samples, masked, p)
    return p, X, Z


def ml_cost(model: Model, data: Dataset, theta, R) -> float:
    """J(theta, R) of paper Eq. 6 without constants (see :meth:`Problem.cost`).

    Parameters
    ----------
    model : Model
    data : Dataset
    theta : array_like, shape (n_parameters,), or mapping
    R : array_like, shape (n_outputs,)
        Noise variances (diagonal of R), unit of z squared; or a full R, shape
        (n_outputs, n_outputs).
    """
    return as_problem(model, data).cost(theta, R)


def concentrated_cost(model: Model, data: Dataset, theta) -> float:
    """Paper Eq. 6 minimised over the diagonal R at theta (see :meth:`Problem.profile_cost`):
    ``sum_j N_j/2 ln(S_j / N_j) + (sum_j N_j) / 2``."""
    return as_problem(model, data).profile_cost(theta)
