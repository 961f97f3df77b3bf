"""The estimator as plain CasADi objects, for use inside larger CasADi workflows.

Three ways in:

- :func:`ml_problem`: the stage-2 NLP (full mode) as symbols: decision vector, data
  parameter, objective with ln|R|, bounds, and the map back to named parameters and R.
  Build a solver once and re-solve it on new data of the same length. From a
  :class:`casest.Problem` it carries experiments, known or full noise, prior penalties,
  fixed parameters and missing outputs.
- :func:`add_to_opti`: the same problem inside a user's ``casadi.Opti``, returning Opti
  variables for the parameters and R, so that users add constraints, variables and cost
  terms and pick their own solver.
- :func:`two_stage_function`: the two-stage estimator (stage 1, then stage 2 from the
  best candidates, as :func:`casest.estimate`) as a ``casadi.Function``: data in; theta,
  R, covariance and a success flag out; its derivatives with respect to the data from the
  implicit function theorem at the optimum, so it can sit inside Opti and be
  differentiated. :func:`estimator_function` is one local IPOPT solve from a given start;
  :func:`ml_cost_function` is the cost as a named Function, and ``Model.function`` the
  per-sample model.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings, noise_floor
from ..data.dataset import DataError, Dataset
from ..models import Model, OptionError
from ..problem.measurement import measurement_of
from ..problem.noise import DiagonalNoise, NoiseModel
from ..problem.problem import Problem, data_symbols, ml_cost_expression
from ..checks import whole_number


__all__ = ["remembering", "MLProblem", "ml_problem", "estimator_function", "ml_cost_function"]


@dataclass
class MLProblem:
    """The full-mode stage-2 NLP as CasADi symbols.

    Decision vector ``x = [s; noise]`` with ``theta = scale * s`` (physical parameters) and
    the noise block ``rho_j = ln R_j`` (diagonal R, the default), the log-Cholesky vector of
    a full R (``CorrelatedNoise``), or nothing (``KnownNoise``: R is a constant); NLP
    parameter ``p`` (the data, :meth:`data_vector`).

    Attributes
    ----------
    model : Model
        The model estimated (a Problem's: experiments expanded, fixed parameters out).
    n_samples : int
    x : casadi.MX, shape (n_parameters + n_noise, 1)
        Decision variables.
    x_names : list of str
        Names of the entries of ``x`` (parameter names, then the noise block's).
    p : casadi.MX
        The data as NLP parameters (see :meth:`data_vector`).
    f : casadi.MX
        The ML objective J of Eq. 6 (with its ln|R| terms, constants dropped; MAP: with the
        prior penalties).
    theta : casadi.MX, shape (n_parameters, 1)
        Physical parameters as an expression of ``x``.
    R : casadi.MX, shape (n_outputs, 1), or (n_outputs, n_outputs) for a full R
        Noise variances (or covariance) as an expression of ``x``.
    scale : ndarray, shape (n_parameters,)
        theta = scale * s.
    problem : Problem or None
        The problem it was built from.
    """

    model: Model
    n_samples: int
    x: ca.MX
    x_names: list
    p: ca.MX
    f: ca.MX
    theta: ca.MX
    R: ca.MX
    scale: np.ndarray
    problem: Problem | None = None

    @property
    def noise(self) -> NoiseModel:
        """The noise model (a problem built from a Model: the default, unknown diagonal R)."""
        return DiagonalNoise() if self.problem is None else self.problem.noise

    @property
    def masked(self) -> bool:
        return self.problem is not None and self.problem.masked

    def nlp(self, objective_scale: float | None = None) -> dict:
        """``{"x", "p", "f"}`` for ``casadi.nlpsol``; ``f`` divided by N unless told otherwise.

        Parameters
        ----------
        objective_scale : float, optional
            Divisor of J (default N).

        Returns
        -------
        dict
        """
        scale = 1.0 / self.n_samples if objective_scale is None else objective_scale
        return {"x": self.x, "p": self.p, "f": self.f * scale}

    def solver(self, settings: SolverSettings | None = None, options: dict | None = None) -> ca.Function:
        """An IPOPT solver for this problem (exact Hessian), built once, re-solvable on new data.

        Parameters
        ----------
        settings : SolverSettings, optional
        options : dict, optional
            Extra ``nlpsol`` options.

        Returns
        -------
        casadi.Function
        """
        opts = (settings or SolverSettings()).nlpsol_options()
        opts.update(options or {})
        return ca.nlpsol(f"casest_ml_{self.model.name}", "ipopt", self.nlp(), opts)

    def data_vector(self, data: Dataset | None = None) -> np.ndarray:
        """Numeric value of ``p``: of the problem's data, or of ``data`` (N samples, the same
        missing-output pattern kind: a problem built without missing outputs takes none).

        Parameters
        ----------
        data : Dataset, optional

        Returns
        -------
        ndarray
        """
        if data is None:
            if self.problem is None:
                raise OptionError("give the data: this problem was built from a model, not a casest.Problem")
            return self.problem.data_vector()
        measurement = measurement_of(self.model)
        measurement.check_data(data)
        if data.has_missing and not self.masked:
            raise DataError("these data have missing outputs, but the problem was built for complete data: build it "
                            "from casest.Problem(model, data) with the data that have them")
        if data.n_samples != self.n_samples:
            raise DataError(f"this problem was built for N = {self.n_samples} samples, the data have {data.n_samples}")
        return measurement.data_vector(data, self.masked)  # a masked problem's p has the mask rows even if none is missing

    def bounds(self, data: Dataset | None = None, settings: SolverSettings | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """``(lbx, ubx)``: parameter boxes (scaled) and the noise floor for the noise block.

        Parameters
        ----------
        data : Dataset, optional
            The data whose noise floor bounds R (default the problem's).
        settings : SolverSettings, optional

        Returns
        -------
        lbx, ubx : ndarray, shape (n_x,) each
        """
        data = data if data is not None else self.problem.data
        floor = noise_floor(data, settings or SolverSettings())
        m = self.model
        lo, hi = self.noise.decision_bounds(floor)
        return np.concatenate([m.lower_bounds / self.scale, lo]), np.concatenate([m.upper_bounds / self.scale, hi])

    def noise_vector(self, R) -> np.ndarray:
        """The noise block of ``x`` for variances ``R`` (shape (n_outputs,); a full R: (n_outputs, n_outputs)).

        Parameters
        ----------
        R : array_like

        Returns
        -------
        ndarray
        """
        return self.noise.decision_vector(R)  # a held R has no decision variables

    def x0(self, theta, R) -> np.ndarray:
        """Decision vector for physical ``theta`` (mapping or array) and noise ``R``.

        Parameters
        ----------
        theta : mapping or array_like, shape (n_parameters,)
        R : array_like, shape (n_outputs,) or (n_outputs, n_outputs)

        Returns
        -------
        ndarray, shape (n_x,)
        """
        theta = self.problem.vector(theta) if self.problem is not None else self.model.vector(theta)
        return np.concatenate([theta / self.scale, self.noise_vector(R)])

    def unpack(self, x) -> tuple[np.ndarray, np.ndarray]:
        """``(theta, R)`` from a numeric decision vector: shapes (n_parameters,), and (n_outputs,)
        (a full R: (n_outputs, n_outputs)).

        Parameters
        ----------
        x : array_like, shape (n_x,)

        Returns
        -------
        theta : ndarray, shape (n_parameters,)
        R : ndarray
        """
        x = np.asarray(x, dtype=float).reshape(-1)
        n = self.model.n_parameters
        theta = x[:n] * self.scale
        return theta, self.noise.decision_covariance(x[n:], self.model)

    def named(self, x) -> dict:
        """Parameters and R by name from a numeric decision vector.

        Parameters
        ----------
        x : array_like, shape (n_x,)

        Returns
        -------
        dict of str to float or ndarray
        """
        theta, R = self.unpack(x)
        out = dict(zip(self.model.parameter_names, theta.tolist()))
        names = self.model.output_names
        if R.ndim == 2:
            out.update({f"R[{a},{b}]": float(R[i, j]) for i, a in enumerate(names) for j, b in enumerate(names) if j <= i})
        else:
            out.update({f"R[{c}]": float(r) for c, r in zip(names, R)})
        return out


def ml_problem(model: Model | Problem, n_samples: int | None = None) -> MLProblem:
    """Build the stage-2 ML problem (see :class:`MLProblem`).

    Parameters
    ----------
    model : Model or Problem
        A :class:`casest.Problem` brings its experiments, noise model, prior penalties,
        fixed parameters and missing outputs, and its N; a Model gives the default problem
        (unknown diagonal R, complete data) for ``n_samples`` samples.
    n_samples : int, optional
        N (a Model only).

    Returns
    -------
    MLProblem
        The NLP's variables, data parameter, cost, bounds and start as CasADi symbols.


    Examples
    --------
    Build the NLP once and solve it with your own solver options:

    >>> import casadi as ca
    >>> import casest
    >>> from casest.interop import ml_problem
    >>> m = casest.load_model_file("scalar2")
    >>> model, data = m.model(), m.simulate(seed=0)
    >>> nlp = ml_problem(model, data.n_samples)
    >>> solver = ca.nlpsol("ml", "ipopt", nlp.nlp(), {"ipopt.print_level": 0, "print_time": False})
    """
    if isinstance(model, Problem):
        problem = model
        model, n_samples, masked = problem.model, problem.n_samples, problem.masked
        noise = problem.noise
        p = ca.MX.sym("data", problem.data_vector().size)
    else:
        n_samples = whole_number(n_samples, "ml_problem(model, n_samples): N must be a positive integer (or build it "
                                            "from a casest.Problem)")
        if measurement_of(model).simulated:
            raise OptionError("a DynamicModel's data vector holds its times, inputs and initial states: build the "
                              "problem from casest.Problem(model, data)")
        problem, masked, noise = None, False, DiagonalNoise()
        p, _, _ = data_symbols(model, n_samples, masked)
    scale = model.scales
    s = ca.MX.sym("s", model.n_parameters)
    theta = s * ca.DM(scale)
    names = list(model.parameter_names)
    rho, variables, R = noise.symbols(model)
    x = s if variables is None else ca.vertcat(s, variables)
    names += noise.variable_names(model.output_names)
    if problem is None:
        f = ml_cost_expression(model, n_samples, theta, rho, p)
    else:
        f = problem.cost_expression(theta, rho, p)
    return MLProblem(model, n_samples, x, names, p, f, theta, R, scale, problem)


def estimator_function(
    model: Model | Problem, n_samples: int | None = None, settings: SolverSettings | None = None,
    name: str = "estimator", remember: bool = True
) -> ca.Function:
    """The ML estimator as a ``casadi.Function``: one full-mode IPOPT solve from a given start.

    From a static Model: ``estimator(signals[n_signals x N], outputs[n_outputs x N],
    theta0[n_parameters]) -> (theta[n_parameters], R[n_outputs])``; R starts at the residual
    mean square at ``theta0`` (physical units).

    From a :class:`casest.Problem` (a static or dynamic model, any noise model, fixed
    parameters, priors, missing outputs): ``estimator(data[n_p], theta0[n_parameters]) ->
    (theta, R)`` with ``data`` in the layout of :meth:`casest.Problem.data_vector` (the same
    N and missing-output pattern kind as the problem's); R is the diagonal (n_outputs), the
    full matrix of a ``CorrelatedNoise``, or the known R.

    It can be called numerically or on CasADi symbols; derivatives of the outputs with
    respect to the data come from IPOPT's parametric sensitivities. Multipliers below 1e-10
    are zeroed (``min_lam``) so that inactive bounds do not enter those sensitivities.

    With ``remember`` (the default) the Function keeps the outputs of its last 16 distinct
    inputs (an ``Opti`` whose data are parameters evaluates it at the same inputs in every
    iteration: one solve instead of one per iteration); that memory is a Python callback, so
    such a Function cannot be saved or code-generated. ``remember=False`` gives the pure CasADi
    Function (the NLP solver and its inputs), which can.

    Parameters
    ----------
    model : Model or Problem
    n_samples : int
        N (a Model only; a Problem brings its own).
    settings : SolverSettings, optional
        IPOPT options and the noise floor.
    name : str
    remember : bool
        Keep the outputs of recent inputs (see above).

    Returns
    -------
    casadi.Function

    Examples
    --------
    One IPOPT solve as a CasADi Function of the data and a start:

    >>> import casest
    >>> from casest.interop import estimator_function
    >>> m = casest.load_model_file("scalar2")
    >>> model, data = m.model(), m.simulate(seed=0)
    >>> F = estimator_function(model, data.n_samples)
    >>> theta, R = F(data.signals.T, data.outputs.T, model.vector(m.TRUTH))
    >>> theta.shape
    (4, 1)

    """
    settings = settings or SolverSettings()
    if isinstance(model, Problem):
        pure = _problem_estimator(model, settings, name)
        return remembering(pure) if remember else pure
    n_samples = whole_number(n_samples, "estimator_function(model, n_samples): N must be a positive integer (or "
                                        "build it from a casest.Problem)")
    pure = _model_estimator(model, int(n_samples), settings, name)
    return remembering(pure) if remember else pure


def _model_estimator(model: Model, n_samples: int, settings: SolverSettings, name: str) -> ca.Function:
    """:func:`estimator_function` of a static Model: ``(signals, outputs, theta0) -> (theta, R)``."""
    problem = ml_problem(model, n_samples)
    solver = problem.solver(settings, {"min_lam": 1e-10})
    X = ca.MX.sym("signals", model.n_signals, n_samples)
    Z = ca.MX.sym("outputs", model.n_outputs, n_samples)
    theta0 = ca.MX.sym("theta0", model.n_parameters)
    p = ca.vertcat(ca.vec(X), ca.vec(Z))
    S0 = ca.sum2((Z - model.function.map(n_samples)(X, theta0)) ** 2)
    mean_square = ca.sum2(Z**2) / n_samples
    floor = settings.noise_floor * ca.fmax(mean_square, 1e-300)
    rho0 = ca.log(ca.fmax(S0 / n_samples, floor))
    lbx = ca.vertcat(ca.DM(model.lower_bounds / problem.scale), ca.log(floor))
    ubx = ca.vertcat(ca.DM(model.upper_bounds / problem.scale), ca.DM.inf(model.n_outputs))
    sol = solver(x0=ca.vertcat(theta0 / ca.DM(problem.scale), rho0), p=p, lbx=lbx, ubx=ubx)
    x = sol["x"]
    n = model.n_parameters
    theta = x[:n] * ca.DM(problem.scale)
    R = ca.exp(x[n:])
    return ca.Function(name, [X, Z, theta0], [theta, R], ["signals", "outputs", "theta0"], ["theta", "R"])


def remembering(function: ca.Function, size: int = 16) -> ca.Function:
    """``function`` with a memory of the outputs of its last ``size`` distinct numeric inputs.

    The evaluation goes through a Python callback (so the result cannot be saved or
    code-generated); its derivatives are ``function``'s own (the Jacobian Function at the given
    outputs), so an ``Opti`` differentiates through it as through ``function``.

    Parameters
    ----------
    function : casadi.Function
    size : int
        Distinct inputs remembered (least recently used forgotten first).

    Returns
    -------
    casadi.Function
        The same inputs and outputs, names included; its attribute ``memory`` is the callback,
        whose ``runs`` counts the evaluations of ``function``.
    """
    callback = _Remembering(function, size)
    symbols = [ca.MX.sym(function.name_in(k), function.sparsity_in(k)) for k in range(function.n_in())]
    outputs = callback(*symbols)
    outputs = list(outputs) if isinstance(outputs, (list, tuple)) else [outputs]
    wrapped = ca.Function(function.name(), symbols, outputs, function.name_in(), function.name_out())
    wrapped.memory = callback
    return wrapped


# callbacks live as long as the process: CasADi holds raw pointers to them
_REMEMBERING: list = []


class _Remembering(ca.Callback):
    """The outputs of ``function`` by the bytes of its inputs (see :func:`remembering`)."""

    def __init__(self, function: ca.Function, size: int):
        ca.Callback.__init__(self)
        self.function, self.size, self.runs = function, int(size), 0
        self._remembered: dict = {}
        self.construct(function.name() + "_remembering", {})
        _REMEMBERING.append(self)

    def get_n_in(self):
        return self.function.n_in()

    def get_n_out(self):
        return self.function.n_out()

    def get_name_in(self, i):
        return self.function.name_in(i)

    def get_name_out(self, i):
        return self.function.name_out(i)

    def get_sparsity_in(self, i):
        return self.function.sparsity_in(i)

    def get_sparsity_out(self, i):
        return self.function.sparsity_out(i)

    def eval(self, args):
        key = tuple(np.asarray(a, dtype=float).tobytes() for a in args)
        if key in self._remembered:
            outputs = self._remembered.pop(key)
        else:
            outputs = self.function(*args)
            outputs = [ca.DM(v) for v in (outputs if isinstance(outputs, (list, tuple)) else [outputs])]
            self.runs += 1
            if len(self._remembered) >= self.size:
                self._remembered.pop(next(iter(self._remembered)))
        self._remembered[key] = outputs  # the most recent last
        return outputs

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        jacobian = self.function.jacobian()
        symbols = jacobian.mx_in()
        return ca.Function(name, symbols, jacobian.call(symbols), inames, onames)


def _problem_estimator(problem: Problem, settings: SolverSettings, name: str) -> ca.Function:
    """:func:`estimator_function` of a Problem: ``(data, theta0) -> (theta, R)``."""
    ml = ml_problem(problem)
    solver = ml.solver(settings, {"min_lam": 1e-10})
    model, N, noise = problem.model, problem.n_samples, problem.noise
    p = ca.MX.sym("data", ml.p.numel())
    theta0 = ca.MX.sym("theta0", model.n_parameters)
    residuals, outputs, counts = problem.measurement.residual_expression(N, theta0, p, problem.masked)
    floor = settings.noise_floor * ca.fmax(ca.sum2(outputs**2) / counts, 1e-300)
    s0 = theta0 / ca.DM(ml.scale)
    noise0 = noise.start_expression(ca.sum2(residuals**2) / counts, floor)
    lo, hi = noise.bounds_expression(floor)
    lbx = ca.vertcat(ca.DM(model.lower_bounds / ml.scale), lo)
    ubx = ca.vertcat(ca.DM(model.upper_bounds / ml.scale), hi)
    x = solver(x0=s0 if noise0 is None else ca.vertcat(s0, noise0), p=p, lbx=lbx, ubx=ubx)["x"]
    theta, R = ca.substitute([ml.theta, ml.R], [ml.x], [x])
    return ca.Function(name, [p, theta0], [theta, R], ["data", "theta0"], ["theta", "R"])


def ml_cost_function(model: Model | Problem, n_samples: int | None = None) -> ca.Function:
    """Eq. 6 as a named Function.

    From a static Model: ``J(theta[n_p], R[n_y], signals[n_s x N], outputs[n_y x N])``. From
    a :class:`casest.Problem` (either model kind, its noise model, priors, fixed parameters,
    missing outputs): ``J(theta[n_p], noise[n_noise], data[n_d])`` with ``noise`` the noise
    block (:meth:`casest.Problem.noise_vector`: ln R_j, or a full R's log-Cholesky vector;
    ignored for a known R) and ``data`` the problem's :meth:`casest.Problem.data_vector`.

    Parameters
    ----------
    model : Model or Problem
    n_samples : int
        N (a Model only).

    Returns
    -------
    casadi.Function
    """
    if isinstance(model, Problem):
        problem = model
        theta = ca.MX.sym("theta", problem.model.n_parameters)
        noise = ca.MX.sym("noise", problem.n_noise)
        data = ca.MX.sym("data", problem.data_vector().size)
        block = problem.noise.cost_block(noise, problem.model)  # a held R: its fixed block
        return ca.Function("ml_cost", [theta, noise, data], [problem.cost_expression(theta, block, data)],
                           ["theta", "noise", "data"], ["J"])
    if n_samples is None:
        raise OptionError("ml_cost_function(model, n_samples): give N, or build it from a casest.Problem")
    theta = ca.MX.sym("theta", model.n_parameters)
    R = ca.MX.sym("R", model.n_outputs)
    X = ca.MX.sym("signals", model.n_signals, n_samples)
    Z = ca.MX.sym("outputs", model.n_outputs, n_samples)
    J = ml_cost_expression(model, n_samples, theta, ca.log(R), ca.vertcat(ca.vec(X), ca.vec(Z)))
    return ca.Function("ml_cost", [theta, R, X, Z], [J], ["theta", "R", "signals", "outputs"], ["J"])
