"""Stage 2 of a static model as a (reweighted) least squares, by Levenberg-Marquardt (MINPACK).

With R diagonal the ML cost of paper Eq. 6 is minimised in theta by the weighted least
squares with weights ``1 / R_j`` where R is the residual mean square at the solution: with
one output (or R known) the least-squares solution itself; with several outputs and R
unknown, least squares reweighted until R settles (each solve warm-started; the fixed point
is a stationary point of Eq. 6, as for :mod:`casest.estimation.gauss_newton`).

Each weighted solve is MINPACK's ``lmder`` (``scipy.optimize.leastsq``, the solver under
lmfit's default method), its loop in C. The residuals and their exact Jacobian come from one
CasADi function evaluated in place through its buffer, compiled once its library is in the
compile cache (:class:`casest._casadi.numerics.CompiledWhenReady`), so a small problem costs
tens of microseconds an iteration where IPOPT's interior-point iteration costs a fraction of a
millisecond. A bounded parameter is mapped to an unbounded one as MINUIT and lmfit do
(``sin`` between two bounds, ``sqrt`` beyond one). The point is accepted only when the
Gauss-Newton decrement there, on the parameters not held by a bound, is below
``DECREMENT_TOL`` (within 1e-6 standard deviations of the optimum the Gauss-Newton step
predicts); otherwise IPOPT solves stage 2 from the start.

MINPACK gives the same bits for the same inputs within a process and across heap states
(``python3 scripts/tools/minpack_determinism.py``: one result over 60 runs on each of five NIST
problems, also with its callbacks returning reused buffers), given the zero column that
:func:`_solve_weighted` appends against SciPy 1.15-1.17's read past the Jacobian.
"""

from __future__ import annotations

import math
import time

import casadi as ca
import numpy as np

from ..._casadi.memory import StructureCache
from ..._casadi.compiled_when_ready import CompiledWhenReady
from ...backend.ipopt import SolverSettings
from ...problem.problem import Problem
from ...estimation.gauss_newton import DECREMENT_TOL, GaussNewtonRun, free_parameters


__all__ = ["least_squares_applies", "small_enough", "levenberg_marquardt_least_squares", "BoundMap", "WeightedResiduals",
           "prediction_function"]

#: MINPACK's xtol and ftol: rounding level (the decrement test decides what is accepted)
MINPACK_TOL = 1e-15
#: the residual MINPACK is handed where the model is not finite (a step there is rejected)
NOT_FINITE = 1e100
#: the status of a solve whose iteration budget (``SolverSettings.max_iter``) ran out, as IPOPT's
OUT_OF_ITERATIONS = "Maximum_Iterations_Exceeded"
#: reweighting rounds of a multi-output problem before IPOPT takes over
MAX_REWEIGHTS = 30
#: "auto" runs Levenberg-Marquardt up to this many residuals (N n_outputs): beyond, IPOPT's compiled sums are faster
AUTO_MAX_RESIDUALS = 1000


# how a parameter is mapped: not bounded, between two bounds, above a lower one, below an upper one
_FREE, _BOTH, _LOW, _UP = range(4)


def _sin(v: float) -> float:
    return math.sin(v) if math.isfinite(v) else math.nan  # NumPy's value where math raises


def _cos(v: float) -> float:
    return math.cos(v) if math.isfinite(v) else math.nan


def least_squares_applies(problem: Problem) -> bool:
    """Whether :func:`levenberg_marquardt_least_squares` solves this problem: a static model, R diagonal
    (estimated or known), no Gaussian priors as penalties.

    Parameters
    ----------
    problem : Problem

    Returns
    -------
    bool
    """
    return bool(problem.noise_term.per_channel and problem.penalty is None)


def small_enough(problem: Problem) -> bool:
    """At most :data:`AUTO_MAX_RESIDUALS` residuals: the uncompiled Jacobian over every sample
    costs less than IPOPT's fixed cost an iteration (larger problems: IPOPT with compiled sums).

    Parameters
    ----------
    problem : Problem

    Returns
    -------
    bool
    """
    return problem.n_samples * problem.model.n_outputs <= AUTO_MAX_RESIDUALS


class BoundMap:
    """MINUIT's map of bounded parameters to unbounded ones (as in lmfit).

    ``x = lo + (hi - lo) (sin u + 1) / 2`` between two bounds, ``x = lo - 1 + sqrt(u^2 + 1)``
    above a lower one, ``x = hi + 1 - sqrt(u^2 + 1)`` below an upper one; free parameters as
    they are. Works on the scaled parameters (order one).

    Parameters
    ----------
    lower, upper : ndarray, shape (n,)
        Bounds (may be infinite).
    """

    def __init__(self, lower: np.ndarray, upper: np.ndarray):
        self.both = np.isfinite(lower) & np.isfinite(upper)
        self.low_only = np.isfinite(lower) & ~self.both
        self.up_only = np.isfinite(upper) & ~self.both
        self.lo = np.where(np.isfinite(lower), lower, 0.0)
        self.hi = np.where(np.isfinite(upper), upper, 0.0)
        self.width = self.hi - self.lo
        self._kind = np.select([self.both, self.low_only, self.up_only], [_BOTH, _LOW, _UP], _FREE).tolist()
        self._lo, self._hi, self._width = self.lo.tolist(), self.hi.tolist(), self.width.tolist()

    def x_and_slope(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The bounded parameters of ``u`` and ``dx/du`` element by element, in one pass (the solver
        asks both at every evaluation).

        Parameters
        ----------
        u : ndarray, shape (n,)

        Returns
        -------
        x : ndarray, shape (n,)
            Inside the bounds.
        slope : ndarray, shape (n,)
        """
        # Python floats: the solver calls this every evaluation, on a few parameters, where each
        # NumPy operation on a masked sub-array costs a microsecond
        xs, slopes = [], []
        for kind, v, lo, hi, width in zip(self._kind, u.tolist(), self._lo, self._hi, self._width):
            if kind == _FREE:
                xs.append(v)
                slopes.append(1.0)
            elif kind == _BOTH:
                xs.append(min(max(lo + width * (_sin(v) + 1.0) / 2.0, lo), hi))
                slopes.append(width * _cos(v) / 2.0)
            else:
                root = math.sqrt(v * v + 1.0)
                xs.append(max(lo - 1.0 + root, lo) if kind == _LOW else min(hi + 1.0 - root, hi))
                slopes.append((v if kind == _LOW else -v) / root)
        return np.array(xs), np.array(slopes)

    def x_of(self, u: np.ndarray) -> np.ndarray:
        """The bounded parameters of ``u`` (see :meth:`x_and_slope`).

        Parameters
        ----------
        u : ndarray, shape (n,)

        Returns
        -------
        ndarray, shape (n,)
            Inside the bounds.
        """
        return self.x_and_slope(u)[0]

    def u_of(self, x: np.ndarray) -> np.ndarray:
        """An unbounded point that maps to ``x``.

        Parameters
        ----------
        x : ndarray, shape (n,)
            Inside the bounds.

        Returns
        -------
        ndarray, shape (n,)
        """
        b, lo_, up_ = self.both, self.low_only, self.up_only
        u = np.asarray(x, dtype=float).copy()
        u[b] = np.arcsin(np.clip(2.0 * (x[b] - self.lo[b]) / self.width[b] - 1.0, -1.0, 1.0))
        u[lo_] = np.sqrt(np.maximum((x[lo_] - self.lo[lo_] + 1.0) ** 2 - 1.0, 0.0))
        u[up_] = np.sqrt(np.maximum((self.hi[up_] - x[up_] + 1.0) ** 2 - 1.0, 0.0))
        return u


_RESIDUAL_FUNCTIONS = StructureCache()


def prediction_function(model, n_samples: int, settings: SolverSettings) -> CompiledWhenReady:
    """``(theta, X) -> (h (n_outputs x N), dh/dtheta (n_outputs x N n_parameters))``, cached per model and N,
    compiled once its library is in the compile cache (:class:`CompiledWhenReady`).

    Parameters
    ----------
    model : Model
    n_samples : int
    settings : SolverSettings
        ``jit_flags`` for the library.

    Returns
    -------
    CompiledWhenReady
    """
    cache = _RESIDUAL_FUNCTIONS.setdefault(model, {})
    if n_samples not in cache:
        theta = ca.MX.sym("theta", model.n_parameters)
        X = ca.MX.sym("X", model.jacobian_function.size1_in(0), n_samples)
        h, J = model.jacobian_function.map(n_samples)(X, theta)
        fun = ca.Function("h_and_jacobian", [theta, X], [ca.densify(h), ca.densify(J)])  # buffers are dense
        cache[n_samples] = CompiledWhenReady(fun, settings.jit_flags)
    return cache[n_samples]


class WeightedResiduals:
    """``theta -> (r, J)``: the weighted residuals ``w (z - h)`` and ``dh/dtheta`` weighted alike.

    Evaluated in place through the CasADi function's buffer (no conversion per call).

    Parameters
    ----------
    problem : Problem
        A static problem.
    settings : SolverSettings, optional
        ``jit`` and ``jit_flags`` (default: compiled once the compile cache holds the library).
    """

    def __init__(self, problem: Problem, settings: SolverSettings | None = None):
        model, data = problem.model, problem.data
        N, ny, n = data.n_samples, model.n_outputs, model.n_parameters
        settings = settings or SolverSettings()
        # jit False: CasADi's virtual machine throughout
        self._ready = prediction_function(model, N, settings) if settings.jit is not False else None
        fun = self._ready.get() if self._ready is not None else prediction_function(model, N, settings).fun
        self._uncompiled = self._ready is None or fun is self._ready.fun
        self.seconds = 0.0  # uncompiled evaluation time, reported by done()
        self._theta = np.zeros(n)
        self._signals = np.ascontiguousarray(data.signals.reshape(-1))  # (N, n_signals) C order = X column-major
        self._h, self._J = np.zeros(ny * N), np.zeros(ny * N * n)
        self._buffer, self._run = fun.buffer()
        for k, arr in enumerate((self._theta, self._signals)):
            self._buffer.set_arg(k, memoryview(arr))
        for k, arr in enumerate((self._h, self._J)):
            self._buffer.set_res(k, memoryview(arr))
        self.mask = data.output_mask()
        self.outputs = data.filled_outputs()
        self.counts = data.observed_counts()
        self.shape = (N, ny, n)

    def __call__(self, theta: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted residuals, shape (N n_outputs,), and weighted Jacobian, shape (N n_outputs, n), sample-major.

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        weights : ndarray, shape (n_outputs,)
            ``1 / sqrt(R_j)``.

        Returns
        -------
        r : ndarray, shape (N n_outputs,)
            Zero where an output was not measured.
        J : ndarray, shape (N n_outputs, n_parameters)
            ``w dh/dtheta`` (the Jacobian of the residuals is ``-J``).
        """
        N, ny, n = self.shape
        self._theta[:] = theta
        if self._uncompiled:
            t0 = time.perf_counter()
            self._run()
            self.seconds += time.perf_counter() - t0
        else:
            self._run()
        w = self.mask * weights  # 0 where not measured
        r = (self.outputs - self._h.reshape(N, ny)) * w  # h is n_outputs x N, column-major
        J = self._J.reshape(N, n, ny).transpose(0, 2, 1) * w[:, :, None]  # n_outputs x (N n), column-major
        return r.reshape(-1), J.reshape(N * ny, n)

    def done(self) -> None:
        """Report the uncompiled evaluation time to the function's :class:`CompiledWhenReady` (which
        compiles the library in the background once that time pays for it)."""
        if self._ready is not None and self._uncompiled:
            self._ready.spent(self.seconds)
        self.seconds = 0.0

    def mean_square(self, theta: np.ndarray) -> np.ndarray:
        """The residual mean square of each output (the ML R at theta).

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.

        Returns
        -------
        ndarray, shape (n_outputs,)
            Unit of each output squared.
        """
        r, _ = self(theta, np.ones(self.shape[1]))
        return np.sum(r.reshape(self.shape[:2]) ** 2, axis=0) / self.counts

    def cost(self, theta: np.ndarray, R: np.ndarray) -> float:
        """J of paper Eq. 6 without constants, ``1/2 sum_k r_k' R^-1 r_k + 1/2 sum_j N_j ln R_j``
        (:meth:`casest.Problem.cost` of a problem without priors), from the compiled residuals.

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        R : ndarray, shape (n_outputs,)
            The noise variances, unit of each output squared.

        Returns
        -------
        float
        """
        return self.cost_of(self(theta, 1.0 / np.sqrt(R))[0], R)

    def cost_of(self, r: np.ndarray, R: np.ndarray) -> float:
        """:meth:`cost` from residuals already weighted by ``1 / sqrt(R)``.

        Parameters
        ----------
        r : ndarray, shape (N n_outputs,)
            Weighted residuals (:meth:`__call__` with weights ``1 / sqrt(R)``).
        R : ndarray, shape (n_outputs,)

        Returns
        -------
        float
        """
        return 0.5 * float(r @ r) + 0.5 * float(self.counts @ np.log(R))


def _solve_weighted(residuals: WeightedResiduals, bounds: BoundMap, scale: np.ndarray, s0: np.ndarray,
                    weights: np.ndarray, max_evaluations: int) -> tuple:
    """One MINPACK solve (``lmder``) of the weighted least squares in the mapped scaled parameters:
    ``(s, evaluations, jacobians)``, to MINPACK's rounding-level tolerances (the caller's decrement
    test decides whether the point is accepted).

    MINPACK is handed one more parameter than the problem has, which enters no residual (a
    Jacobian column of zeros, the last one): SciPy 1.15-1.17's ``qrfac`` recomputes a column's
    norm one element too far (scipy/scipy#24323, fixed in 1.18), which on the last column reads
    past the Jacobian's memory, so that the iterates depended on what the heap held before. A
    column of zeros is never pivoted away from the last place and its norm is never recomputed;
    its step is zero (nothing couples it to the residuals), so the iterates are those of the
    problem itself.
    """
    from scipy.optimize import leastsq  # on first use: importing scipy.optimize costs ~0.3 s

    n, n_residuals = s0.size, residuals.shape[0] * residuals.shape[1]
    jacobian_out = np.zeros((n + 1, n_residuals))  # rows: parameters (col_deriv), the last one zero
    kept: dict = {}

    def residual(u_padded):
        u = u_padded[:n]
        s, slope = bounds.x_and_slope(u)
        r, J = residuals(s * scale, weights)
        if not (np.isfinite(r).all() and np.isfinite(J).all()):
            kept.clear()
            return np.full(r.size, NOT_FINITE)
        np.negative((J * (scale * slope)).T, out=jacobian_out[:n])  # -w dh/du, exact negation
        kept["u"] = u.copy()
        return r

    def jacobian(u_padded):
        if "u" not in kept or not np.array_equal(kept["u"], u_padded[:n]):  # the Jacobian at the point asked for
            residual(u_padded)
        return jacobian_out if "u" in kept else np.zeros((n + 1, n_residuals))

    u0 = np.append(bounds.u_of(np.asarray(s0, dtype=float)), 0.0)
    u, _, info, _, _ = leastsq(residual, u0, Dfun=jacobian, col_deriv=1, full_output=True, xtol=MINPACK_TOL,
                               ftol=MINPACK_TOL, gtol=0.0, maxfev=max_evaluations)
    return bounds.x_of(u[:n]), int(info["nfev"]), int(info.get("njev", 0))


def least_squares_decrement(J: np.ndarray, r: np.ndarray) -> float:
    """The Gauss-Newton decrement ``b' (J'J)^-1 b`` with ``b = J'r`` as ``||Q'r||^2`` from the QR
    factors of J: the squared length of r's projection on J's columns, accurate where J'J is
    too ill-conditioned to solve (NIST Thurber).

    Parameters
    ----------
    J : ndarray, shape (m, k)
    r : ndarray, shape (m,)

    Returns
    -------
    float
        Twice the cost decrease the full Gauss-Newton step predicts.
    """
    if J.shape[1] == 0:
        return 0.0
    qtr = np.linalg.qr(J)[0].T @ r
    return float(qtr @ qtr)


def levenberg_marquardt_least_squares(problem: Problem, theta0: np.ndarray, R0: np.ndarray, floor: np.ndarray,
                          settings: SolverSettings, residuals: WeightedResiduals | None = None) -> GaussNewtonRun:
    """Minimise the ML cost of Eq. 6 of a static problem with diagonal R by Levenberg-Marquardt.

    Parameters
    ----------
    problem : Problem
        A problem for which :func:`least_squares_applies`.
    theta0 : ndarray, shape (n_parameters,)
        Start, physical units, inside the bounds.
    R0 : ndarray, shape (n_outputs,)
        The known R (held), or the start of an estimated R.
    floor : ndarray, shape (n_outputs,)
        Lower bound of an estimated R.
    settings : SolverSettings
        ``max_iter`` bounds the residual evaluations (about one an iteration) over all
        reweighting rounds, at most ``50 (n_parameters + 1)`` (a solve that needs more goes to IPOPT).
    residuals : WeightedResiduals, optional
        The problem's residuals (built here when not given).

    Returns
    -------
    GaussNewtonRun
        With the cost at its end; ``success`` only when the decrement test passes (status ``"Solve_Succeeded"``);
        otherwise the point reached, with status ``"Maximum_Iterations_Exceeded"`` when
        ``max_iter`` ran out (a multi-start's short budget) and ``"Not_Verified"`` when
        it stopped or reached its own cap without passing the test.
    """
    model = problem.model
    scale = model.scales
    bounds = BoundMap(model.lower_bounds / scale, model.upper_bounds / scale)
    residuals = residuals or WeightedResiduals(problem, settings)
    estimated = problem.noise.estimated
    several = estimated and model.n_outputs > 1
    s = np.asarray(theta0, dtype=float) / scale
    R = np.asarray(R0, dtype=float).copy()
    evaluations = jacobians = 0
    # residual evaluations over all rounds: one an iteration (the Jacobian comes with it), so
    # max_iter counts iterations as it does for IPOPT; 50 (n + 1), half lmder's default, caps it
    budget = min(settings.max_iter + 1, 50 * (model.n_parameters + 1))
    for _ in range(MAX_REWEIGHTS if several else 1):
        # each weighted solve to rounding, so that with several outputs the reweighting's fixed point is
        # the ML optimum to rounding too (a 1e-6 std error per round would stop R's updates early)
        s, nfev, njev = _solve_weighted(residuals, bounds, scale, s, 1.0 / np.sqrt(R), budget - evaluations)
        evaluations, jacobians = evaluations + nfev, jacobians + njev
        if not estimated:
            break
        R_new = np.maximum(residuals.mean_square(s * scale), floor)
        settled = np.all(np.abs(R_new - R) <= 1e-12 * R_new)
        R = R_new
        if settled or not several or evaluations >= budget:
            break
    theta = s * scale
    r, J = residuals(theta, 1.0 / np.sqrt(R))
    residuals.done()
    Js = J * scale
    b = Js.T @ r  # minus the gradient of the weighted cost, scaled units
    free = free_parameters(s, model.lower_bounds / scale, model.upper_bounds / scale, b)
    finite = bool(np.all(np.isfinite(r)) and np.all(np.isfinite(Js)))
    left = least_squares_decrement(Js[:, free], r) if finite else np.inf
    success = bool(finite and left <= DECREMENT_TOL)
    # the caller's iteration budget ran out (not the solver's own cap): reported as IPOPT reports it
    out_of_iterations = evaluations >= budget == settings.max_iter + 1
    status = "Solve_Succeeded" if success else OUT_OF_ITERATIONS if out_of_iterations else "Not_Verified"
    return GaussNewtonRun(theta, R, success, status, max(jacobians, 1), evaluations, cost=residuals.cost_of(r, R))
