"""Filter error as flight-test practice formulates it (Maine and Iliff, SIAM J. Appl. Math. 41,
1981; Jategaonkar, *Flight Vehicle System Identification*, Ch. 5): the innovation formulation.

The unknowns are the model's parameters theta and the process-noise distribution F (diagonal,
``F F' = Q_c`` on the named states); the measurement noise is not a decision variable. Instead
the *innovation* covariance R is estimated in closed form, ``R = sum e e' / N`` (as output error
estimates its R), and the relaxation alternates:

1. with R held, theta and F by Gauss-Newton (scoring) on ``1/2 sum e' R^-1 e`` with exact
   sensitivities of the innovations, as the textbook's program does; where the optimum breaks
   the textbook's constraint ``diag(K C) <= 1`` (which keeps ``G G' = R - C P C'`` a
   covariance), IPOPT solves step 1 again with the constraint;
2. R from the innovations at the new estimate;
3. F compensated for the change of R (Jategaonkar's Eq. 5.41):
   ``F_i <- F_i sum_j C_ji^2 R_old,jj^-1 sqrt(R_new,jj / R_old,jj) / sum_j C_ji^2 R_old,jj^-1``,

until ``J = N/2 ln det R`` changes by less than ``SETTLE_COST`` (relative) and the estimate by
less than ``SETTLE_STEP`` (relative). The gain is the steady-state one of the model linearised at
an operating point: the first state and input, as the textbook's program does
(``operating_point="first"``), or the time-average of the predicted states and the inputs,
renewed after every round (``"mean"``). ``P`` solves the textbook's continuous Riccati equation
``A P + P A' - P C' R^-1 C P / dt + F F' = 0`` (Newton-Kleinman steps from the discrete equation's
solution) and ``K = P C' R^-1``. The states are propagated by the nonlinear model and corrected by
K. The std are the Cramer-Rao bounds of step 1 at the estimate (the inverse of
``sum de' R^-1 de``). The implied measurement noise ``G G' = R - C P C'`` is reported as R.

The graph (innovations, their sensitivities, the constrained NLP) is built once per model
structure, number of samples and set of noisy states; the record, the operating point and R are
its parameters, so a second estimate with the same model skips the build.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..options import OperatingPoint, choices
from .._casadi.memory import StructureCache
from ..backend.ipopt import SolverSettings, run_ipopt
from ..estimation.solve.gauss_newton import ROUNDING_DECREMENT
from ..data.dataset import Dataset
from ..models.dynamic import DynamicModel
from ..status import Note, NoteCode, Outcome, StdReason
from .ekf_model import ekf_step_functions
from .filter_error_result import FilterErrorEstimate
from .gain_sensitivities import gain_pass_derivatives
from .scoring import fisher_information, likelihood_terms, polish, score
from .steady_filter_error import check_steady_data, doubling, reference_point, steady_record_columns, steady_step

__all__ = ["innovation_gain", "innovation_estimate", "compensate_process_noise", "InnovationProblem",
           "OPERATING_POINTS"]

#: relaxation rounds (R update, F compensation) before the estimate is reported as not settled
MAX_ROUNDS = 100
#: the relaxation has settled when J = N/2 ln det R changes by less than this, relative (its rounding
#: on 600 samples is some 5e-11) ...
SETTLE_COST = 1e-10
#: ... and no estimated value moves by more than this, relative
SETTLE_STEP = 1e-9
#: rounds are polished (Gauss-Newton to 1e-9 std) once the last one moved the estimate less than this
POLISH_FROM = 1e-4
#: Riccati doublings (each squares the steps it stands for) of the discrete start
DOUBLINGS = 16
#: Newton-Kleinman steps on the continuous Riccati equation (quadratic convergence from the start)
NEWTON_STEPS = 8
#: where the gain is linearised: the first state and input, or the mean predicted state and input
OPERATING_POINTS = choices(OperatingPoint)

_GAINS = StructureCache()
_PROBLEMS = StructureCache()


def innovation_gain(model: DynamicModel) -> ca.Function:
    """``(theta, f, R_inv, x_ref, u_ref, dt) -> (K, P, C)``: the steady gain of the innovation
    formulation at the reference point (built once per model structure).

    Parameters
    ----------
    model : DynamicModel

    Returns
    -------
    casadi.Function
        ``f``: the diagonal of F, shape (n_states,); ``R_inv``: the inverse innovation covariance,
        shape (n_outputs, n_outputs); ``dt``: the sampling interval (s).
    """
    cache = _GAINS.setdefault(model, {})
    if "gain" not in cache:
        cache["gain"] = _build_gain(model)
    return cache["gain"]


def _build_gain(model: DynamicModel) -> ca.Function:
    propagate, measure = ekf_step_functions(model)
    n, nu, ny = model.n_states, len(model.inputs), model.n_outputs
    theta, f, Ri = ca.SX.sym("theta", model.n_parameters), ca.SX.sym("f", n), ca.SX.sym("R_inv", ny, ny)
    x_ref, u_ref, dt = ca.SX.sym("x_ref", n), ca.SX.sym("u_ref", nu), ca.SX.sym("dt")
    u_held = ca.repmat(u_ref, model.step_function.size1_in(1) // nu, 1) if nu else ca.SX(0, 1)
    _, Qd, Phi = propagate(x_ref, ca.SX.zeros(n, n), u_held, u_held, dt, theta, ca.diag(f**2), u_ref, ca.SX.zeros(nu))
    _, C = measure(x_ref, u_ref, theta)
    H = doubling(Phi.T, ca.mtimes([C.T, Ri, C]), Qd, DOUBLINGS)  # the discrete equation: Newton's start
    eye = ca.SX.eye(n)
    # the textbook's continuous equation A P + P A' - P M P + F F' = 0, M = C' R^-1 C / dt, by
    # Newton-Kleinman: each step the Lyapunov equation (A - P M) X + X (A - P M)' = -(F F' + P M P)
    Ac = ca.jacobian(model.rhs_function(x_ref, u_ref, theta), x_ref)
    M, FF = ca.mtimes([C.T, Ri, C]) / dt, ca.diag(f**2)
    P = H
    for _ in range(NEWTON_STEPS):
        closed = Ac - ca.mtimes(P, M)
        lyapunov = ca.kron(eye, closed) + ca.kron(closed, eye)
        P = ca.reshape(ca.solve(lyapunov, -ca.vec(FF + ca.mtimes([P, M, P]))), n, n)
        P = 0.5 * (P + P.T)
    K = ca.mtimes([P, C.T, Ri])
    return ca.Function("innovation_gain", [theta, f, Ri, x_ref, u_ref, dt], [K, P, C],
                       ["theta", "f", "R_inv", "x_ref", "u_ref", "dt"], ["K", "P", "C"])


def compensate_process_noise(f: np.ndarray, C: np.ndarray, R_old: np.ndarray, R_new: np.ndarray) -> np.ndarray:
    """Jategaonkar's Eq. 5.41: F revised for the change of the innovation covariance.

    Parameters
    ----------
    f : ndarray, shape (n_states,)
        The diagonal of F before the revision.
    C : ndarray, shape (n_outputs, n_states)
        The linearised observation matrix.
    R_old, R_new : ndarray, shape (n_outputs, n_outputs)
        The innovation covariance before and after its update.

    Returns
    -------
    ndarray, shape (n_states,)
    """
    ri_old, ri_new = np.diag(np.linalg.inv(R_old)), np.diag(np.linalg.inv(R_new))
    weight = (C**2).T @ ri_old
    with np.errstate(invalid="ignore", divide="ignore"):
        factor = ((C**2).T @ (ri_old * np.sqrt(ri_old / ri_new))) / weight
    return np.where(weight > 0, f * factor, f)


class InnovationProblem:
    """The innovation formulation over N samples as CasADi functions of ``w`` and ``p``.

    ``w = [theta / scales; f of the noisy states]``;
    ``p = [vec(R); vec(D); last; x0 data; x_ref; u_ref; dt; f of every state]`` (the last used
    where a state is not noisy). Built once per model structure, N and noisy set
    (:meth:`of`).
    """

    def __init__(self, model: DynamicModel, N: int, noisy: tuple):
        step, last_fn = steady_step(model)
        n, nu, ny, npar = model.n_states, len(model.inputs), model.n_outputs, model.n_parameters
        self.model, self.N, self.noisy = model, N, noisy
        w = ca.MX.sym("w", npar + len(noisy))
        R, D = ca.MX.sym("R", ny, ny), ca.MX.sym("D", step.size1_in(1), N - 1)
        last, d0 = ca.MX.sym("last", nu + ny), ca.MX.sym("x0_data", len(model.initial_from_data))
        x_ref, u_ref, dt, f_all = ca.MX.sym("x_ref", n), ca.MX.sym("u_ref", nu), ca.MX.sym("dt"), ca.MX.sym("f", n)
        theta = w[:npar] * ca.DM(model.scales)
        f = ca.vertcat(*[w[npar + noisy.index(i)] if i in noisy else f_all[i] for i in range(n)])
        Ri = ca.inv(R)
        K, P, C = innovation_gain(model)(theta, f, Ri, x_ref, u_ref, dt)
        x0 = model.initial_function(theta, d0)
        acc, dk = ca.MX.sym("acc", n), ca.MX.sym("d", D.shape[0])
        th_s, K_s, Ri_s = ca.MX.sym("th", npar), ca.MX.sym("K", n, ny), ca.MX.sym("Ri", ny, ny)
        xn, _, ek = step(acc, dk, th_s, K_s, Ri_s)
        advance = ca.Function("innovation_advance", [acc, dk, th_s, K_s, Ri_s], [xn, ek])
        X, E = advance.mapaccum("innovation_run", N - 1)(x0, D, ca.repmat(theta, 1, N - 1), ca.repmat(K, 1, N - 1),
                                                          ca.repmat(Ri, 1, N - 1))
        X = ca.horzcat(x0, X)
        _, e_last = last_fn(X[:, -1], last, theta, Ri)
        E = ca.horzcat(E, e_last)
        self.w, self.p = w, ca.vertcat(ca.vec(R), ca.vec(D), last, d0, x_ref, u_ref, dt, f_all)
        self.derivatives = gain_pass_derivatives(model, self.w, self.p, E, ca.vec(R), (theta, K, x0), ny * ny)
        self.values = ca.Function("innovation_values", [self.w, self.p], [E, ca.diag(ca.mtimes(K, C)), C, P, X])
        self._cost, self._kc, self._solver = 0.5 * ca.sum1(ca.sum2(E * ca.mtimes(Ri, E))), ca.diag(ca.mtimes(K, C)), None
        self._constraint = None

    @classmethod
    def of(cls, model: DynamicModel, N: int, noisy: tuple) -> "InnovationProblem":
        """The problem of this model structure, N and noisy set (built on first use).

        Parameters
        ----------
        model : DynamicModel
        N : int
            Samples of the record (at least 2).
        noisy : tuple of int
            The states whose F is estimated.

        Returns
        -------
        InnovationProblem
        """
        cache = _PROBLEMS.setdefault(model, {})
        key = (int(N), tuple(noisy))
        if key not in cache:
            cache[key] = cls(model, int(N), tuple(noisy))
        return cache[key]

    def parameters(self, data, R: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray,
                   f_all: np.ndarray) -> np.ndarray:
        """The parameter vector ``p`` of a record.

        Parameters
        ----------
        data : Dataset or tuple
            Uniformly sampled, complete outputs, ``N`` samples; or its :meth:`record_part`,
            computed once for the many ``p`` of one estimate.
        R : ndarray, shape (n_outputs, n_outputs)
            The innovation covariance.
        x_ref : ndarray, shape (n_states,)
        u_ref : ndarray, shape (n_inputs,)
            The operating point of the gain.
        f_all : ndarray, shape (n_states,)
            F of every state (used for the states not estimated).

        Returns
        -------
        ndarray
        """
        record, dt = self.record_part(data) if isinstance(data, Dataset) else data
        return np.concatenate([np.asarray(R, dtype=float).reshape(-1, order="F"), record, x_ref, u_ref, [dt], f_all])

    def record_part(self, data: Dataset) -> tuple[np.ndarray, float]:
        """The record's share of ``p`` (``[vec(D); last; x0 data]``) and its sampling interval (s)."""
        dt = check_steady_data(self.model, data)
        D, last = steady_record_columns(self.model, data)
        return np.concatenate([D.reshape(-1, order="F"), last, self.model.initial_values(data)]), dt

    def constraint(self) -> ca.Function:
        """``(w, p) -> (diag(K C), its Jacobian in w)`` (built on first use)."""
        if self._constraint is None:
            self._constraint = ca.Function("innovation_kc", [self.w, self.p], [self._kc, ca.jacobian(self._kc, self.w)])
        return self._constraint

    def constrained_solver(self, settings: SolverSettings) -> ca.Function:
        """IPOPT on step 1 with ``diag(K C) <= 1`` (built on first use)."""
        if self._solver is None:
            self._solver = ca.nlpsol("innovation_filter_error", "ipopt",
                                     {"x": self.w, "p": self.p, "f": self._cost / self.N, "g": self._kc},
                                     settings.nlpsol_options())
        return self._solver


@dataclass
class _Relaxation:
    """Where the relaxation stands: the decision vector, R, and what the rounds took."""

    w: np.ndarray
    R: np.ndarray
    x_ref: np.ndarray
    u_ref: np.ndarray
    rounds: int = 0
    iterations: int = 0
    constrained_rounds: int = 0
    settled: bool = False
    status: str = ""


def innovation_estimate(model: DynamicModel, data: Dataset, process_noise: np.ndarray, noisy: list, theta0: np.ndarray,
                        settings: SolverSettings, operating_point: str = "first") -> FilterErrorEstimate:
    """The innovation formulation's relaxation (module docstring).

    Parameters
    ----------
    model : DynamicModel
    data : Dataset
        Uniformly sampled, complete outputs.
    process_noise : ndarray, shape (n_states,)
        Start of the intensities (F_i^2), fixed for the states not in ``noisy``.
    noisy : list of int
        The states whose F is estimated.
    theta0 : ndarray, shape (n_parameters,)
    settings : SolverSettings
        ``max_iter`` bounds each step 1; ``tol`` and the rest are IPOPT's for a constrained step 1.
    operating_point : {"first", "mean"}
        Where the gain is linearised (module docstring).

    Returns
    -------
    FilterErrorEstimate
    """
    t0 = time.perf_counter()
    check_steady_data(model, data)
    problem = InnovationProblem.of(model, data.n_samples, tuple(noisy))
    npar, N = model.n_parameters, data.n_samples
    f_all = np.sqrt(np.asarray(process_noise, dtype=float))
    x0 = np.asarray(model.initial_function(theta0, model.initial_values(data))).reshape(-1)
    x_ref, u_ref = reference_point(data, x0[None, :], first=True)

    record = problem.record_part(data)

    def parameters(state: _Relaxation) -> np.ndarray:
        return problem.parameters(record, state.R, state.x_ref, state.u_ref, f_all)

    lower = np.concatenate([model.lower_bounds / model.scales, np.zeros(len(noisy))])
    upper = np.concatenate([model.upper_bounds / model.scales, np.full(len(noisy), np.inf)])
    state = _Relaxation(np.clip(np.concatenate([theta0 / model.scales, f_all[noisy]]), lower, upper),
                        np.atleast_2d(np.cov(data.outputs.T, bias=True)), x_ref, u_ref)
    E = np.asarray(problem.values(state.w, parameters(state))[0])
    state.R = E @ E.T / N  # the start's innovations, not the outputs' spread
    J_prev, previous, moved = np.inf, state.w.copy(), np.inf
    while state.rounds < MAX_ROUNDS and not state.settled:
        state.rounds += 1
        p = parameters(state)
        run, _ = score(problem.derivatives, p, state.w, lower, upper, settings.max_iter)
        # the polish matters once the rounds move the estimate little: its fixed point is then exact
        w, polished = polish(problem.derivatives, p, run.x, lower, upper) if moved < POLISH_FROM else (run.x, 0)
        state.iterations += run.iterations + polished
        state.status = run.status
        E, kc, C, _, X = (np.asarray(v) for v in problem.values(w, p))
        if np.any(kc.reshape(-1) > 1.0 + 1e-12):
            w, E, C, X = _constrained_step(problem, state, w, p, lower, upper, settings)
        R_new = E @ E.T / N
        f = f_all.copy()
        f[noisy] = w[npar:]
        w[npar:] = compensate_process_noise(f, C, state.R, R_new)[noisy]
        J = 0.5 * N * float(np.linalg.slogdet(R_new)[1])
        moved = np.max(np.abs(w - previous) / np.maximum(np.abs(w), 1e-8), initial=0.0)
        state.settled = abs(J - J_prev) <= SETTLE_COST * max(1.0, abs(J)) and moved <= SETTLE_STEP
        state.w, state.R, J_prev, previous = w, R_new, J, w.copy()
        if operating_point == "mean":
            state.x_ref, state.u_ref = reference_point(data, X.T, first=False)
    information = fisher_information(problem.derivatives, state.w, parameters(state))
    values = [np.asarray(v) for v in problem.values(state.w, parameters(state))]
    return _result(problem, data, state, f_all, information, values, operating_point, time.perf_counter() - t0)


def _constrained_step(problem: InnovationProblem, state: _Relaxation, w: np.ndarray, p: np.ndarray, lower, upper,
                      settings: SolverSettings):
    """Step 1 again by IPOPT with ``diag(K C) <= 1``, from the unconstrained optimum."""
    run = run_ipopt(problem.constrained_solver(settings), x0=w, lbx=lower, ubx=upper, p=p, lbg=-np.inf, ubg=1.0)
    state.iterations += run.iterations
    state.constrained_rounds += 1
    state.status = run.status
    if not run.success and _constrained_stationary(problem, run.x, p, lower, upper):
        state.status = "Solved_To_Rounding"  # IPOPT's stop short of its tolerance, verified
    E, _, C, _, X = (np.asarray(v) for v in problem.values(run.x, p))
    return run.x.copy(), E, C, X


def _constrained_stationary(problem: InnovationProblem, w: np.ndarray, p: np.ndarray, lower, upper) -> bool:
    """Whether ``w`` is a first-order point of step 1 with ``diag(K C) <= 1``, to 1e-4 std.

    Feasible to 1e-6; the gradient less its best non-negative combination of the active
    constraints' gradients (bounds and ``diag(K C) = 1``) has a decrement ``r' F^-1 r`` below
    ``ROUNDING_DECREMENT``, the test scoring's rounding stop passes.
    """
    from scipy.optimize import nnls

    kc, dkc = (np.asarray(v) for v in problem.constraint()(w, p))
    kc = kc.reshape(-1)
    if np.any(kc > 1.0 + 1e-6):  # IPOPT's own feasibility tolerance (constr_viol_tol 1e-4) is looser
        return False
    _, g, F = likelihood_terms(problem.derivatives, w, p)
    span = np.maximum(1.0, np.abs(w))
    normals = [dkc[i] for i in np.flatnonzero(kc >= 1.0 - 1e-6)]
    normals += [np.eye(w.size)[j] for j in np.flatnonzero(upper - w <= 1e-8 * span)]
    normals += [-np.eye(w.size)[j] for j in np.flatnonzero(w - lower <= 1e-8 * span)]
    residual = g
    if normals:
        A = np.array(normals).T  # g + A lambda = 0 with lambda >= 0 at a constrained minimum
        multipliers, _ = nnls(A, -g)
        residual = g + A @ multipliers
    try:
        return float(residual @ np.linalg.solve(F, residual)) <= ROUNDING_DECREMENT
    except np.linalg.LinAlgError:
        return False


def _result(problem: InnovationProblem, data: Dataset, state: _Relaxation, f_all: np.ndarray, information: np.ndarray,
            values: list, operating_point: str, seconds: float) -> FilterErrorEstimate:
    """The estimate with the Cramer-Rao bounds of step 1 and the implied measurement noise."""
    model, noisy = problem.model, list(problem.noisy)
    npar, scale, N, ny = model.n_parameters, model.scales, data.n_samples, model.n_outputs
    _, kc, C, P, _ = values
    to_natural = np.concatenate([scale, np.ones(len(noisy))])
    notes = [_formulation_note(state, operating_point)]
    try:
        cov = np.linalg.inv(information) * np.outer(to_natural, to_natural)
        std_all = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        cov, std_all = np.full(information.shape, np.nan), np.full(information.shape[0], np.nan)
        notes.append(Note("the information matrix is singular: some parameters are not identifiable from this record; "
                          "fix them or add excitation", NoteCode.NOT_IDENTIFIABLE))
    if not state.settled:
        notes.append(Note(f"the relaxation (R update, F compensation) did not settle in {MAX_ROUNDS} rounds: the "
                          "estimate is the last round's", NoteCode.NOT_VERIFIED))
    GG = state.R - C @ P @ C.T
    if np.any(np.diag(GG) < 0):
        notes.append(Note("the implied measurement noise R - C P C' has a negative variance: the process noise takes "
                          "more than the innovations hold", NoteCode.NOISE_FLOOR))
    converged = state.status in ("Solve_Succeeded", "Solved_To_Acceptable_Level", "Solved_To_Rounding")
    success = state.settled and converged and bool(np.all(np.isfinite(std_all)))
    f = f_all.copy()
    f[noisy] = state.w[npar:]
    logdet = float(np.linalg.slogdet(state.R)[1])
    return FilterErrorEstimate(
        model_name=model.name, parameter_names=tuple(model.parameter_names), theta=state.w[:npar] * scale,
        std=std_all[:npar], std_reasons=["" if np.isfinite(s) else "singular information" for s in std_all[:npar]],
        std_reason_codes=[None if np.isfinite(s) else StdReason.SINGULAR for s in std_all[:npar]],
        active_bounds=[None] * npar, lower_bounds=model.lower_bounds, upper_bounds=model.upper_bounds,
        parameter_units=tuple(p.unit for p in model.parameters),
        process_noise={model.state_names[i]: float(f[i] ** 2) for i in range(model.n_states) if f[i] > 0},
        process_noise_std={model.state_names[i]: float(2 * f[i] * s) for i, s in zip(noisy, std_all[npar:])},
        output_names=tuple(model.output_names), output_units=tuple(model.output_units),
        R=np.diag(GG).copy(), R_std=np.zeros(ny), R_estimated=True, covariance=cov,
        cost=0.5 * N * ny + 0.5 * N * logdet,
        log_likelihood=-0.5 * N * ny * (1 + np.log(2 * np.pi)) - 0.5 * N * logdet,
        success=success, status=state.status, outcome=Outcome.CONVERGED if success else Outcome.NOT_CONVERGED,
        n_iterations=state.iterations, n_samples=N, seconds=seconds, filter=None, notes=notes,
        formulation="innovation")


def _formulation_note(state: _Relaxation, operating_point: str) -> Note:
    where = ("the first state and input" if operating_point == "first" else
             "the mean predicted state and input, renewed every round")
    constrained = (f"; diag(K C) <= 1 was active in {state.constrained_rounds} round(s) (IPOPT)"
                   if state.constrained_rounds else "")
    return Note(f"innovation formulation: theta and F by Gauss-Newton with the innovation covariance R in closed form, "
                f"F compensated after each update of R (Jategaonkar Eq. 5.41); one gain linearised at {where}; "
                f"{state.rounds} round(s), {state.iterations} Gauss-Newton iterations in all{constrained}",
                NoteCode.NOISE_MODEL)
