"""The estimation problem as one object: model, experiments, noise model, priors, fixed parameters.

A :class:`Problem` resolves what the user declared (one or several experiments, a noise
model, Gaussian priors as penalties, parameters held fixed, missing outputs) into the one
model and data set that every stage works on, and owns the one implementation of the
residuals, of the ML cost of paper Eq. 6 with its ln|R| terms (numeric values come from
the same per-sample CasADi functions whose exact derivatives stage 2 and the covariance
use, :mod:`casest.backend.sums`), of the residual Jacobian and of the data vector. Stage 1
(:func:`casest.sweep`), stage 2 (:func:`casest.solve_stage2`), the covariance
(:func:`casest.parameter_uncertainty`), the embedding API, the baselines and the
Monte-Carlo code all take a Problem where they take a model and data.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from .._casadi.evaluation import evaluate
from ..backend.noise_terms import NoiseTerm, term_of_covariance
from ..backend.penalty import GaussianPenalty
from ..backend.sums import Record, data_outside_graph
from ..data.dataset import DataError, Dataset
from ..models import Model, ModelError, OptionError
from .measurement import (  # noqa: F401  (data_symbols, ml_cost_expression, ...: their old import path)
    data_symbols,
    data_vector,
    measurement_of,
    ml_cost_expression,
    sum_data_symbols,
)
from .problem_graphs import ProblemGraphs
from .noise import (  # noqa: F401  (cholesky_vector, covariance_of: their old import path)
    DiagonalNoise,
    NoiseModel,
    cholesky_vector,
    covariance_of,
)


__all__ = ["Problem", "as_problem", "ml_cost_expression", "data_symbols", "sum_data_symbols",
           "data_vector",
           "cholesky_vector",
           "covariance_of", "NOISE_KINDS"]

#: The labels of the noise models (``NoiseModel.kind``): estimated diagonal (paper Eq. 6), known, estimated full.
NOISE_KINDS = ("diagonal", "known", "full")


#: evaluations a Problem remembers (the last ones)
_REMEMBERED = 32


class Problem(ProblemGraphs):
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
        Parameters held at these values (with those declared ``Parameter(fixed=True)`` or
        with equal bounds ``Parameter(name, v, v)``, held
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
    undeclared_units : dict of str to str
        Data columns whose file gives a unit the model does not declare (see
        :attr:`Dataset.undeclared_units`), over every data set given.
    alignment : dict of str to AlignedColumn
        Data columns resampled onto a common time base by a log reader (see
        :attr:`Dataset.alignment`), over every data set given.
    noise : NoiseModel
        The noise model (for several experiments with a known R per output: one std per
        output and experiment).
    noise_kind : {"diagonal", "known", "full"}
        ``noise.kind``, a label for reports.
    penalty : tuple of (ndarray, ndarray) or None
        ``(means, precisions)`` of the Gaussian priors used as penalties.
    separate_noise : bool

    Examples
    --------
    One declaration (data, noise model, fixed parameters) for every stage:

    >>> import casest
    >>> m = casest.load_model_file("scalar2")
    >>> problem = casest.Problem(m.model(), m.simulate(seed=0), noise=casest.KnownNoise({"z": 0.3}),
    ...                          fixed={"a": 1.0})
    >>> problem.model.parameter_names
    ('b', 'c', 'd')
    >>> est = casest.estimate(problem)
    >>> est.values["a"], est.noise_estimated
    (1.0, False)

    """

    def __init__(self, model: Model, data, *, stage1_data: Dataset | None = None,
                 noise: NoiseModel | None = None, fixed: Mapping[str, float] | None = None,
                 prior_penalty: bool = False, separate_noise: bool = True):
        declared = measurement_of(model)  # refuses anything but a Model or a DynamicModel
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
        if data is None:
            raise OptionError("give the data: a casest.Dataset, or several (experiments) as a list or a mapping")
        self.undeclared_units = _undeclared_units(data, stage1_data)
        self.alignment = _merged_attribute(data, stage1_data, "alignment")
        if isinstance(data, Dataset):
            full_model = model
        else:  # several experiments sharing the parameters
            full_model, data, self.experiments = declared.stack_experiments(data, separate_noise)
            if stage1_data is not None and full_model is not model:
                raise OptionError("with several experiments and separate noise (or several manoeuvres of a dynamic "
                                  "model), stage 1 runs on the experiments themselves; leave stage1_data out (or use "
                                  "separate_noise=False with a static model)")
            if separate_noise:
                self.noise = noise.for_experiments(model.output_names, self.experiments)
        self.full_model = full_model
        held = {p.name: p.nominal for p in full_model.parameters if p.fixed}
        held.update({p.name: float(p.lb) for p in full_model.parameters if p.lb == p.ub})  # equal bounds hold it
        held.update({str(k): float(v) for k, v in dict(fixed or {}).items()})
        self.held = held
        self.model = full_model.with_fixed(held) if held else full_model
        self.measurement = declared if self.model is model else measurement_of(self.model)
        for d in (data, stage1_data):
            if d is not None:
                self.measurement.check_data(d)
                d.check_size(self.model)  # a record built for_estimation=False is checked here
        self.data = data
        self.stage1_data = stage1_data
        self.noise.bind(self.model)
        self.noise.check_data(data)
        self.prior_penalty = bool(prior_penalty)
        self.penalty = GaussianPenalty.of(self.model) if prior_penalty else None
        self._stage1 = None
        # costs and mean squares already evaluated (a start's cost is asked by the multi-start and
        # the solve from it): the data and model never change after construction
        self._evaluated: dict = {}

    def _remembered(self, key: tuple, compute):
        if key not in self._evaluated:
            if len(self._evaluated) >= _REMEMBERED:
                self._evaluated.pop(next(iter(self._evaluated)))
            self._evaluated[key] = compute()
        return self._evaluated[key]

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
    def noise_term(self) -> NoiseTerm:
        """R's parametrisation in the cost and the sums (``noise.term``: diagonal or log-Cholesky)."""
        return self.noise.term

    @property
    def full_mode_reason(self) -> str | None:
        """Why stage 2 must solve every parameter together (full mode), or None when the reduced
        and alternating modes apply: output error, a full R, or priors as penalties say so."""
        if self.penalty is not None:
            return "Gaussian priors as penalties"
        return self.measurement.full_mode_reason or self.noise_term.full_mode_reason

    @property
    def n_noise(self) -> int:
        """Length of the noise block of the decision vector (ln R_j, or the log-Cholesky vector)."""
        return self.noise.vector_size(self.model.n_outputs)

    def describe_noise(self) -> str:
        """One line for reports.

        Returns
        -------
        str
        """
        return self.noise.describe(self.model)

    def with_data(self, data, stage1_data: Dataset | None = None) -> "Problem":
        """The same problem (model, noise model, priors, fixed parameters) on other data.

        Parameters
        ----------
        data : Dataset, or sequence / mapping of Dataset
        stage1_data : Dataset, optional

        Returns
        -------
        Problem
        """
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

        Returns
        -------
        model : Model or DynamicModel
        data : Dataset
        weighted : bool
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
    @property
    def known_R(self) -> np.ndarray | None:
        """The known noise variances, shape (n_outputs,), or None where R is estimated (the noise
        model's, held once in :attr:`noise`)."""
        return self.noise.given_variances(self.model)

    def vector(self, theta) -> np.ndarray:
        """Parameters of :attr:`model` as a vector, shape (n_parameters,).

        ``theta`` is a mapping (names of fixed parameters are ignored), a vector of the
        estimated parameters, or a vector of all declared parameters (the fixed entries
        are dropped).

        Parameters
        ----------
        theta : mapping or array_like
            Parameters (physical units), as described above.

        Returns
        -------
        ndarray, shape (n_parameters,)
        """
        if isinstance(theta, Mapping):
            return self.model.vector({k: v for k, v in theta.items() if k not in self.held})
        arr = np.asarray(theta, dtype=float).reshape(-1)
        if self.held and arr.size == self.full_model.n_parameters != self.model.n_parameters:
            keep = [i for i, n in enumerate(self.full_model.parameter_names) if n not in self.held]
            arr = arr[keep]
        return self.model.vector(arr)

    def residuals(self, theta) -> np.ndarray:
        """``z_k - h(x_k, theta)``, shape (N, n_outputs), NaN where an output was not measured.

        Parameters
        ----------
        theta : mapping or array_like
            Parameters (physical units): see :meth:`vector`.

        Returns
        -------
        ndarray, shape (N, n_outputs)
            Output units.
        """
        return self.data.outputs - self.predict(theta)

    @property
    def dynamic(self) -> bool:
        """The outputs go through states simulated from theta (a DynamicModel: output error)."""
        return self.measurement.simulated

    def predict(self, theta) -> np.ndarray:
        """Noise-free outputs at the data's samples, shape (N, n_outputs) (a dynamic model: simulated).

        Parameters
        ----------
        theta : mapping or array_like
            Parameters (physical units): see :meth:`vector`.

        Returns
        -------
        ndarray, shape (N, n_outputs)
        """
        return self.measurement.predict(self.vector(theta), self.data)

    @property
    def output_model(self) -> Model:
        """The static model of the output equation (the model itself, for a static model)."""
        return self.measurement.output_model

    def jacobian(self, theta) -> np.ndarray:
        """d h / d theta at every sample, shape (N * n_outputs, n_parameters), sample-major;
        the rows of outputs not measured are zero.

        Parameters
        ----------
        theta : mapping or array_like
            Parameters (physical units): see :meth:`vector`.

        Returns
        -------
        ndarray, shape (N n_outputs, n_parameters)
        """
        J = self.measurement.jacobian(self.vector(theta), self.data)
        return J * self.data.output_mask().reshape(-1)[:, None] if self.masked else J

    def residual_mean_square(self, theta) -> np.ndarray:
        """Per-output mean square of the measured residuals, ``sum_k r_kj^2 / N_j``, shape (n_outputs,).

        The ML estimate of the diagonal R at theta.

        Parameters
        ----------
        theta : mapping or array_like
            Parameters (physical units): see :meth:`vector`.

        Returns
        -------
        ndarray, shape (n_outputs,)
            Unit of each output squared.
        """
        theta = self.vector(theta)

        def mean_square():
            resid = np.nan_to_num(self.residuals(theta))
            return np.sum(resid**2, axis=0) / self.data.observed_counts()

        return self._remembered(("mean_square", theta.tobytes()), mean_square).copy()

    def residual_covariance(self, theta) -> np.ndarray:
        """``r' r / N``, shape (n_outputs, n_outputs): the ML estimate of a full R at theta.

        Parameters
        ----------
        theta : mapping or array_like
            Parameters (physical units): see :meth:`vector`.

        Returns
        -------
        ndarray, shape (n_outputs, n_outputs)
        """
        resid = np.nan_to_num(self.residuals(theta))
        return resid.T @ resid / self.n_samples

    def noise_vector(self, R) -> np.ndarray:
        """The noise block of the decision vector: ``ln R_j`` (R the diagonal, shape (n_outputs,)),
        or the log-Cholesky vector of a full R (shape (n_outputs, n_outputs)).

        Parameters
        ----------
        R : array_like, shape (n_outputs,) or (n_outputs, n_outputs)

        Returns
        -------
        ndarray
            Shape (n_outputs,), or (n_cholesky(n_outputs),) for a full R.
        """
        return self.noise.to_vector(R)

    def noise_of(self, vector) -> np.ndarray:
        """Inverse of :meth:`noise_vector`: the diagonal R, or the full R of a :class:`casest.CorrelatedNoise`.

        Parameters
        ----------
        vector : array_like
            The noise block of the decision vector.

        Returns
        -------
        ndarray, shape (n_outputs,) or (n_outputs, n_outputs)
        """
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
        return self._remembered(("cost", theta.tobytes(), R.shape, R.tobytes()), lambda: self._cost(theta, R))

    def _cost(self, theta: np.ndarray, R: np.ndarray) -> float:
        term = term_of_covariance(R)  # the R given decides: variances or a full matrix
        if self.masked and not term.takes_mask:
            raise DataError("a full R needs complete data")
        outside = data_outside_graph(self.n_samples)
        sums, scale = self.measurement.cost_sums(self.n_samples, self.masked, term, outside)
        w = np.concatenate([theta / scale, term.block_of(R)])
        masked = self.masked
        X = self.measurement.signals_at(theta, self.data)  # a dynamic model's: simulated states, inputs
        Z = self.measurement.outputs_of(self.data, masked)
        if outside:
            with Record(X, Z) as record:
                (value,) = evaluate(sums.cost, w, record.handle)
        else:
            (value,) = evaluate(sums.cost, w, X.T, Z.T)
        return float(value[0]) * self.n_samples + self.penalty_value(theta)

    def profile_cost(self, theta) -> float:
        """J at theta with R at its ML value there (known R: the known R), plus any prior penalty.

        The common yardstick for comparing estimates of different methods on the same data.

        Parameters
        ----------
        theta : mapping or array_like
            Parameters (physical units): see :meth:`vector`.

        Returns
        -------
        float
        """
        theta = self.vector(theta)
        return self.cost(theta, self.noise.profile(self, theta))

    def penalty_value(self, theta) -> float:
        """``sum P_i (theta_i - mu_i)^2 / 2`` of the priors used as penalties; 0 without them.

        Parameters
        ----------
        theta : mapping or array_like
            Parameters (physical units): see :meth:`vector`.

        Returns
        -------
        float
        """
        return 0.0 if self.penalty is None else self.penalty.value(theta)

    def start_point(self, theta0, floor: np.ndarray, R0=None) -> tuple[float, np.ndarray]:
        """Where stage 2 starts from ``theta0``: the cost J there and the noise R it starts with.

        R is the known R, else the given ``R0``, else the ML R at ``theta0`` (the residual
        mean square, held above ``floor``; a full R: the residual covariance plus the floor
        on its diagonal).

        Returns
        -------
        cost : float
        R : ndarray, shape (n_outputs,), or (n_outputs, n_outputs) for a full R

        Parameters
        ----------
        theta0 : mapping or array_like
        floor : ndarray, shape (n_outputs,)
            The noise floor (:func:`casest.backend.noise_floor`).
        R0 : array_like, optional
        """
        theta0 = self.vector(theta0)
        R = self.noise.start(self, theta0, floor, R0)
        return self.cost(theta0, R), R


def as_problem(model, data=None, **options) -> Problem:
    """A :class:`Problem` from a model and data, or the problem given.

    Parameters
    ----------
    model : Model, DynamicModel or Problem
    data : Dataset, list or mapping of Dataset, optional
        Must be None (or the problem's data) when ``model`` is a Problem.
    **options
        Keyword arguments of :class:`Problem`.

    Returns
    -------
    Problem
        ``model`` itself if it is a Problem, else ``Problem(model, data, **options)``.
    """
    if isinstance(model, Problem):
        if data is not None and data is not model.data:
            return model.with_data(data)
        return model
    if data is None:
        raise OptionError("give the data: a Dataset, or several (experiments), or a casest.Problem")
    return Problem(model, data, **options)


def _undeclared_units(data, stage1_data) -> dict:
    """Columns of the given data sets whose file unit the model does not declare (name: unit)."""
    return _merged_attribute(data, stage1_data, "undeclared_units")


def _merged_attribute(data, stage1_data, attribute: str) -> dict:
    """A per-column dict attribute of the given data sets (one or several), merged."""
    if isinstance(data, Mapping):
        sets = list(data.values())
    else:  # one Dataset or a list / tuple of them (an iterator is left for stack_experiments to read)
        sets = list(data) if isinstance(data, (list, tuple)) else [data]
    found = {}
    for d in sets + [stage1_data]:
        if isinstance(d, Dataset):
            found.update(getattr(d, attribute, {}))
    return found
