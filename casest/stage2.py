"""Stage 2: the maximum-likelihood NLP solved by IPOPT with exact CasADi Hessians.

The cost is paper Eq. (6) with R diagonal and unknown::

    J(theta, R) = 1/2 sum_k sum_j (z_kj - h_j(x_k, theta))**2 / R_j + N/2 sum_j ln R_j

R is log-parametrised: the decision variables are ``rho_j = ln R_j``, bounded below by
a noise floor ``R_j >= noise_floor * mean_k(z_kj**2)`` so that exactly fitting data
(ln R -> -inf) stay well posed. Parameters are scaled to order one
(``theta = scale * s``). IPOPT minimises ``J / N``. Sums over samples are CasADi
map-reduce nodes with the data as NLP parameters, so the expression graph does not grow
with N and a solver built once is reused for every data set of the same length.

Modes
-----
``full``
    Decision variables: all of theta and rho.
``reduced``
    Decision variables: xi2 and rho; xi1 is the weighted least-squares solution inside
    the NLP (normal equations, differentiated exactly) and is recovered afterwards by QR.
``alternating``
    The paper's outer loop (Eq. 26): xi2 with R fixed, then R from the residuals, until
    every R_j changes by less than ``alternating_tol`` (5 %).
"""

from __future__ import annotations

import time
import weakref
from dataclasses import dataclass, field, replace
from typing import Mapping

import casadi as ca
import numpy as np

from .data import DataError, Dataset
from .model import Model, OptionError
from .separate import Partition
from .numerics import evaluate
from .status import Note, NoteCode, Outcome, note_code

__all__ = [
    "SolverSettings",
    "Stage2Result",
    "solve_stage2",
    "ml_cost",
    "MODES",
    "active_bounds",
    "residual_square_sum",
    "residual_mean_square",
    "concentrated_cost",
    "start_point",
]

MODES = ("full", "reduced", "alternating")

_ACCEPTABLE_STATUSES = (
    "Solved_To_Acceptable_Level",
    "Search_Direction_Becomes_Too_Small",
    "Restoration_Failed",
    "Error_In_Step_Computation",
    "Maximum_Iterations_Exceeded",
)


@dataclass(frozen=True)
class SolverSettings:
    """Settings of the stage-2 NLP.

    Attributes
    ----------
    tol : float
        IPOPT's convergence tolerance (on the scaled problem J/N).
    max_iter : int
        IPOPT's iteration limit.
    start_max_iter : int
        When :func:`casest.estimate` runs stage 2 from several starts, each first gets
        this many iterations; a start that is still running then and is the most
        promising (below every converged solution) continues up to ``max_iter``. Starts
        that drift into degenerate regions (two terms merging, a column of A vanishing)
        otherwise spend the full ``max_iter`` there.
    print_level : int
        IPOPT's print level (0 silent, 5 verbose).
    noise_floor : float
        Lower bound of each R_j relative to the channel's mean square ``mean(z_j**2)``.
    alternating_tol : float
        Relative change of every R_j that ends the alternating loop (paper Eq. 26: 5 %).
    max_alternations : int
        Iteration limit of the alternating loop.
    newton_acceptance : float
        When IPOPT stops short of its tolerance (e.g. ``Search_Direction_Becomes_Too_Small``
        on exactly fitting data), the point is accepted if the exact Newton step on the
        free variables is shorter than this (scaled units) and the Hessian is positive
        definite there.
    jit : bool or None
        Compile the loops that sum the cost, gradient and Hessian over the samples to C
        with the system compiler (CasADi's ``shell`` compiler, gcc or cc; 0.1-0.3 s per
        function, once per model and N). Sums over samples are then 3-8x faster.
        ``None`` (default): compile when N >= ``jit_min_samples`` and a compiler is on
        the PATH. Compilation happens in a temporary folder.
    jit_flags : tuple of str
        Compiler flags for ``jit``.
    jit_min_samples : int
        N from which ``jit=None`` compiles.
    threads : int or None
        Threads for the sums over samples; ``None``: one per core, with at least 2000
        samples per thread (so small problems stay serial). Monte-Carlo workers pass 1.
    ipopt : mapping, optional
        Extra options, merged over the defaults (keys without the ``ipopt.`` prefix).
    """

    tol: float = 1e-10
    max_iter: int = 1000
    start_max_iter: int = 150
    print_level: int = 0
    noise_floor: float = 1e-20
    alternating_tol: float = 0.05
    max_alternations: int = 50
    newton_acceptance: float = 1e-6
    jit: bool | None = None
    jit_flags: tuple = ("-O2",)
    jit_min_samples: int = 2000
    threads: int | None = None
    ipopt: Mapping | None = None

    def resolved_jit(self, n_samples: int) -> bool:
        """Whether sums over ``n_samples`` are compiled (see ``jit``)."""
        if self.jit is None:
            from .numerics import compiler_available

            return n_samples >= self.jit_min_samples and compiler_available()
        return bool(self.jit)

    def resolved_threads(self, n_samples: int) -> int:
        """Threads for sums over ``n_samples`` (see ``threads``)."""
        from .numerics import default_threads

        return default_threads(n_samples) if self.threads is None else max(1, int(self.threads))

    def nlpsol_options(self) -> dict:
        opts = {
            "print_time": False,
            # IPOPT handles a NaN/inf trial point by cutting the step; CasADi's printout of it is noise
            "show_eval_warnings": False,
            "ipopt.print_level": self.print_level,
            "ipopt.sb": "yes",
            "ipopt.tol": self.tol,
            "ipopt.max_iter": self.max_iter,
            "ipopt.hessian_approximation": "exact",
            # the adaptive barrier update copes far better with the ML cost's curvature
            # away from the optimum (NIST MGH09 from start 1: 144 iterations against 857)
            "ipopt.mu_strategy": "adaptive",
            # bound multipliers start at mu / slack, not at 1: J/N has gradients far below 1
            # near a good start, and unit multipliers let the barrier push the iterate off the
            # optimum onto a plateau (NIST BoxBOD from the stage-1 best: J/N 3.14 -> 4.20)
            "ipopt.bound_mult_init_method": "mu-based",
            # near an exact fit the line search cannot resolve the cost's round-off and IPOPT
            # would iterate on at the optimum (NIST Lanczos3: 1000 iterations, now 245); a
            # stop on a step this small is accepted only after the exact Newton check
            "ipopt.tiny_step_tol": 1e-9,
        }
        for key, value in dict(self.ipopt or {}).items():
            opts[key if key.startswith("ipopt.") else "ipopt." + key] = value
        return opts


@dataclass
class Stage2Result:
    """Raw outcome of stage 2 (the public result is :class:`casest.Estimate`).

    Attributes
    ----------
    theta : ndarray, shape (n_parameters,)
    R : ndarray, shape (n_outputs,)
    cost : float
        J(theta, R) of Eq. 6 (constants dropped).
    success : bool
    status : str
        IPOPT's return status (or the loop's, in alternating mode).
    message : str
    n_iterations : int
        IPOPT iterations (summed over solves).
    mode : str
        Mode that produced the result (may differ from the one asked, see notes).
    notes : list of str
    seconds : float
    outcome : Outcome
        How it ended, as a code.
    """

    theta: np.ndarray
    R: np.ndarray
    cost: float
    success: bool
    status: str
    message: str
    n_iterations: int
    mode: str
    notes: list = field(default_factory=list)
    seconds: float = 0.0
    outcome: Outcome = Outcome.NOT_CONVERGED


# ----------------------------------------------------------------------------- symbolic parts
def _sum_over_samples(per_sample: ca.Function, n_samples: int, name: str) -> ca.Function:
    """Map a per-sample Function over N samples (last inputs broadcast) and sum its outputs.

    For graphs that CasADi differentiates (the embedding API of :mod:`casest.embed`): a
    plain map followed by ``sum2``, whose derivatives build faster than those of the
    map-reduce form. The estimator's own sums, whose derivatives are per-sample
    expressions, use :func:`casest.sums.map_sum`.
    """
    inputs = [ca.MX.sym(per_sample.name_in(k), per_sample.sparsity_in(k)) for k in range(per_sample.n_in())]
    data = [ca.MX.sym(f"{per_sample.name_in(k)}_all", per_sample.size1_in(k), n_samples) for k in range(2)]
    outputs = per_sample.map(n_samples)(*(data + inputs[2:]))
    outputs = outputs if isinstance(outputs, (list, tuple)) else [outputs]
    return ca.Function(name, data + inputs[2:], [ca.sum2(o) for o in outputs])


def residual_square_sum(model: Model, n_samples: int) -> ca.Function:
    """(X[n_s x N], Z[n_y x N], theta) -> S[n_y] = sum_k (z_k - h(x_k, theta))**2."""
    z = ca.SX.sym("z", model.n_outputs)
    r2 = (z - model.h) ** 2
    per_sample = ca.Function("r2", [model.x, z, model.theta], [r2], ["x", "z", "theta"], ["r2"])
    return _sum_over_samples(per_sample, n_samples, "r2_sum")


def _normal_equations(model: Model, partition: Partition, n_samples: int, threads: int = 1, jit: bool = False,
                      jit_flags=("-O2",), masked: bool = False) -> ca.Function:
    """(X, Z, xi2, w) -> (sum A'WA, sum A'W(z-b)) with W = diag(w); A'WA as vec (n1^2).

    ``masked``: Z holds ``[z; m]`` per sample (2 n_y rows) and W = diag(w * m).
    """
    from .sums import map_sum

    ny = model.n_outputs
    z = ca.SX.sym("z", 2 * ny if masked else ny)
    xi2 = ca.SX.sym("xi2", partition.n_nonlinear)
    w = ca.SX.sym("w", ny)
    A = partition.A(model.x, xi2)
    b = partition.b(model.x, xi2)
    weight = w * z[ny:] if masked else w
    WA = A * ca.repmat(weight, 1, partition.n_linear)
    per_sample = ca.Function(
        "ne", [model.x, z, xi2, w], [ca.vec(ca.mtimes(A.T, WA)), ca.mtimes(WA.T, z[:ny] - b)], ["x", "z", "xi2", "w"],
        ["AtWA", "AtWr"]
    )
    return map_sum(per_sample, n_samples, threads, "ne_sum", jit, jit_flags)


def data_symbols(model: Model, n_samples: int, masked: bool = False) -> tuple[ca.MX, ca.MX, ca.MX]:
    """The NLP parameter ``p = [vec(X); vec(Z)]`` and its views X (n_s x N), Z (n_y x N).

    ``masked``: Z is ``[z; m]`` (2 n_y x N), m = 1 where an output was measured, 0 where not.
    """
    ns, ny, N = model.n_signals, model.n_outputs * (2 if masked else 1), n_samples
    p = ca.MX.sym("data", (ns + ny) * N)
    # vertsplit keeps only offsets; p[a:b] would store N-long index vectors
    signals, outputs = ca.vertsplit(p, [0, ns * N, (ns + ny) * N])
    return p, ca.reshape(signals, ns, N), ca.reshape(outputs, ny, N)


def ml_objective(S: ca.MX, rho: ca.MX, n_samples: int) -> ca.MX:
    """Eq. 6 from the residual sums of squares S_j and rho_j = ln R_j (constants dropped)."""
    return 0.5 * ca.sum1(ca.exp(-rho) * S) + 0.5 * n_samples * ca.sum1(rho)


def _assemble(partition: Partition, xi1: ca.MX, xi2: ca.MX) -> ca.MX:
    parts = [None] * (partition.n_linear + partition.n_nonlinear)
    for k, i in enumerate(partition.linear_index):
        parts[i] = xi1[k]
    for k, i in enumerate(partition.nonlinear_index):
        parts[i] = xi2[k]
    return ca.vertcat(*parts)


class _Problem:
    """One stage-2 NLP (mode, model, partition, N), built once and reused.

    IPOPT gets the cost, its gradient and the upper triangle of its Hessian as sums of
    per-sample exact derivatives (:mod:`casest.sums`) through nlpsol's ``grad_f`` and
    ``hess_lag`` options, so CasADi never differentiates through the N-sample graph.
    In ``reduced`` mode xi1 = xi1*(xi2, R) solves the weighted normal equations, the
    gradient is the full one at that point (dJ/dxi1 = 0 there) and the Hessian is the
    Schur complement ``H_uu - H_u1 H_11^-1 H_1u`` of the full Hessian, which is the exact
    Hessian of the reduced cost.
    """

    def __init__(self, model: Model, partition: Partition, n_samples: int, mode: str, settings: SolverSettings,
                 penalty: tuple | None = None, masked: bool = False, full_noise: bool = False):
        from .sums import ml_sums, n_cholesky, symmetric

        self.model, self.partition, self.n_samples, self.mode = model, partition, n_samples, mode
        n, N = model.n_parameters, n_samples
        # the noise block of w: ln R_j (diagonal R), or the log-Cholesky vector of a full R
        ny = n_cholesky(model.n_outputs) if full_noise else model.n_outputs
        if full_noise and (mode != "full" or masked):
            raise ValueError("a full unknown R needs the full stage-2 mode and complete data")
        p, X, Z = data_symbols(model, N, masked)
        sums = ml_sums(model, N, model.scales, settings.resolved_threads(N), settings.resolved_jit(N), settings.jit_flags,
                       masked, full_noise)
        if mode == "full":
            self.scale = model.scales
            w = ca.MX.sym("w", n + ny)
            theta = w[:n] * ca.DM(self.scale)
            f = sums.cost(w, X, Z)
            f_g, g = sums.gradient(w, X, Z)
            H = sums.hessian(w, X, Z)
            if penalty is not None:
                # Gaussian priors as penalties (MAP): + sum P_i (theta_i - mu_i)^2 / 2, over N like the cost
                mean, precision = (ca.DM(v) for v in penalty)
                scale = ca.DM(self.scale)
                dev = theta - mean
                term = 0.5 * ca.sum1(precision * dev**2) / N
                f, f_g = f + term, f_g + term
                g = g + ca.vertcat(precision * dev * scale / N, ca.MX.zeros(ny))
                H = H + ca.diag(ca.vertcat(precision * scale**2 / N, ca.DM.zeros(ny)))
        else:
            if penalty is not None:
                raise ValueError("Gaussian priors as penalties need the full stage-2 mode")
            idx1, idx2 = list(partition.linear_index), list(partition.nonlinear_index)
            self.scale = model.scales[idx2]
            w = ca.MX.sym("w", len(idx2) + ny)
            xi2 = w[: len(idx2)] * ca.DM(self.scale)
            rho = w[len(idx2) :]
            if partition.n_linear:
                n1 = partition.n_linear
                M, rhs = _normal_equations(
                    model, partition, N, settings.resolved_threads(N), settings.resolved_jit(N), settings.jit_flags,
                    masked,
                )(X, Z, xi2, ca.exp(-rho))
                xi1 = ca.solve(ca.reshape(M, n1, n1), rhs)
            else:
                xi1 = ca.MX(0, 1)
            theta = _assemble(partition, xi1, xi2)
            w_full = ca.vertcat(theta / ca.DM(model.scales), rho)
            keep = idx2 + list(range(n, n + ny))
            f = sums.cost(w_full, X, Z)
            f_g, g_full = sums.gradient(w_full, X, Z)
            g = g_full[keep]
            H_full = symmetric(sums.hessian(w_full, X, Z))
            H = H_full[keep, keep]
            if idx1:
                H = H - ca.mtimes(H_full[keep, idx1], ca.solve(H_full[idx1, idx1], H_full[idx1, keep]))
            H = ca.triu(H)
        self.n_s = w.numel() - ny
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", 0)
        grad_f = ca.Function("grad_f", [w, p], [f_g, g], ["x", "p"], ["f", "grad"])
        hess_lag = ca.Function("hess_lag", [w, p, lam_f, lam_g], [lam_f * H], ["x", "p", "lam_f", "lam_g"], ["hess"])
        self._nlp = {"x": w, "p": p, "f": f}
        self._options = settings.nlpsol_options()
        self._options.update({"grad_f": grad_f, "hess_lag": hess_lag, "calc_lam_p": False})
        self._solvers: dict = {}
        self.theta_of = ca.Function("theta_of", [w, p], [theta])
        self.newton = ca.Function("newton", [w, p], [g, symmetric(H)])

    def solver(self, max_iter: int) -> ca.Function:
        """The IPOPT solver with this iteration limit (the derivative Functions are shared)."""
        if max_iter not in self._solvers:
            options = dict(self._options, **{"ipopt.max_iter": int(max_iter)})
            solver = ca.nlpsol(f"casest_{self.mode}", "ipopt", self._nlp, options)
            # the buffer allocates the solver's work memory (about 1 s at N = 1e6): made once
            self._solvers[max_iter] = (solver, solver.buffer())
        return self._solvers[max_iter]

    def solve(self, w0: np.ndarray, lbw: np.ndarray, ubw: np.ndarray, p: np.ndarray, max_iter: int = 1000
              ) -> tuple[np.ndarray, dict]:
        """Run IPOPT through the solver's buffer interface (the data are read in place).

        Returns the solution ``w`` and IPOPT's statistics.
        """
        _, (buffer, run) = self.solver(max_iter)
        self._args = [np.ascontiguousarray(a, dtype=float) for a in (w0, p, lbw, ubw)]
        w, f = np.zeros(len(self._args[0])), np.zeros(1)
        for k, arr in enumerate(self._args):  # x0, p, lbx, ubx
            buffer.set_arg(k, memoryview(arr))
        buffer.set_res(0, memoryview(w))
        buffer.set_res(1, memoryview(f))
        run()
        return w, dict(buffer.stats())


_CACHE: "weakref.WeakKeyDictionary[Model, dict]" = weakref.WeakKeyDictionary()


def _problem(model: Model, partition: Partition, n_samples: int, mode: str, settings: SolverSettings,
             penalty: tuple | None = None, masked: bool = False, full_noise: bool = False) -> _Problem:
    # the iteration limit selects one of the problem's solvers, not a new build
    key = (partition.linear, mode, n_samples, repr(replace(settings, max_iter=0)),
           None if penalty is None else tuple(map(tuple, penalty)), masked, full_noise)
    per_model = _CACHE.setdefault(model, {})
    if key not in per_model:
        per_model[key] = _Problem(model, partition, n_samples, mode, settings, penalty, masked, full_noise)
    return per_model[key]


def data_vector(data: Dataset) -> np.ndarray:
    """The NLP parameter vector p = [vec(X); vec(Z)] (column-major, sample by sample).

    With missing outputs Z is ``[z; m]`` per sample: z with 0 where not measured, m the mask.
    """
    if data.has_missing:
        z = np.hstack([data.filled_outputs(), data.output_mask()])
        return np.concatenate([data.signals.reshape(-1), z.reshape(-1)])
    return np.concatenate([data.signals.reshape(-1), data.outputs.reshape(-1)])


def ml_cost(model: Model, data: Dataset, theta, R) -> float:
    """J(theta, R) of paper Eq. 6 without constants.

    Parameters
    ----------
    theta : array_like, shape (n_parameters,) or mapping
    R : array_like, shape (n_outputs,)
        Noise variances (diagonal of R), unit of z squared.
    """
    theta = model.vector(theta)
    R = np.asarray(R, dtype=float).reshape(-1)
    resid = data.outputs - model.predict(theta, data.signals)  # NaN where not measured
    return float(0.5 * np.nansum(resid**2 / R) + 0.5 * np.sum(data.observed_counts() * np.log(R)))


def residual_mean_square(model: Model, data: Dataset, theta) -> np.ndarray:
    """Per-output mean square of the measured residuals at theta, sum_k r_kj^2 / N_j, shape (n_outputs,).

    The ML noise variance for that theta (diagonal R); missing outputs are left out.
    """
    resid = np.nan_to_num(data.outputs - model.predict(model.vector(theta), data.signals))  # 0 where not measured
    return np.sum(resid**2, axis=0) / data.observed_counts()


def concentrated_cost(model: Model, data: Dataset, theta) -> float:
    """Paper Eq. 6 minimised over the diagonal R at theta: ``sum_j N_j/2 ln(S_j / N_j) + (sum_j N_j) / 2``.

    The common yardstick for comparing estimates of different methods on the same data.
    """
    return ml_cost(model, data, theta, np.maximum(residual_mean_square(model, data, theta), 1e-300))


def start_point(model: Model, data: Dataset, theta0, floor: np.ndarray, R0=None, known_R=None,
                penalty: tuple | None = None, full_R: bool = False) -> tuple[float, np.ndarray]:
    """Where stage 2 starts from ``theta0``: the cost J there and the noise R it starts with.

    R is the known R, else the given ``R0``, else the residual mean square at ``theta0``
    (held above the noise floor); with ``full_R`` the residual covariance r'r / N plus the
    floor on its diagonal. One prediction over the data.

    Returns
    -------
    cost : float
        Paper Eq. 6 at (theta0, R), plus the prior penalty when given.
    R : ndarray, shape (n_outputs,), or (n_outputs, n_outputs) with ``full_R``
    """
    theta0 = model.vector(theta0)
    resid = np.nan_to_num(data.outputs - model.predict(theta0, data.signals))  # 0 where not measured
    counts = data.observed_counts()
    if full_R:
        R = resid.T @ resid / data.n_samples + np.diag(floor)
        L = np.linalg.cholesky(R)
        cost = 0.5 * np.sum(np.linalg.solve(L, resid.T) ** 2) + data.n_samples * np.sum(np.log(np.diag(L)))
    else:
        if known_R is not None:
            R = np.asarray(known_R, dtype=float).reshape(-1)
        else:
            R = np.sum(resid**2, axis=0) / counts if R0 is None else np.asarray(R0, dtype=float).reshape(-1)
            R = np.maximum(R, floor)
        cost = 0.5 * np.sum(resid**2 / R) + 0.5 * np.sum(counts * np.log(R))
    return float(cost) + prior_penalty_value(penalty, theta0), R


def prior_penalty_value(penalty: tuple | None, theta: np.ndarray) -> float:
    """``sum P_i (theta_i - mu_i)^2 / 2`` for ``penalty = (means, precisions)``; 0 without one."""
    if penalty is None:
        return 0.0
    mean, precision = penalty
    return float(0.5 * np.sum(precision * (np.asarray(theta, dtype=float) - mean) ** 2))


def noise_floor(data: Dataset, settings: SolverSettings) -> np.ndarray:
    """Lower bound of each R_j, shape (n_outputs,)."""
    ms = data.output_mean_square()
    return settings.noise_floor * np.where(ms > 0, ms, 1.0)


def active_bounds(theta: np.ndarray, lb: np.ndarray, ub: np.ndarray, scale: np.ndarray, tol: float = 1e-7) -> list:
    """Per parameter: ``"lower"``, ``"upper"`` or ``None``, with ``tol`` in scaled units."""
    out = []
    for t, lo, hi, s in zip(theta, lb, ub, scale):
        if np.isfinite(lo) and abs(t - lo) <= tol * max(s, abs(lo)):
            out.append("lower")
        elif np.isfinite(hi) and abs(t - hi) <= tol * max(s, abs(hi)):
            out.append("upper")
        else:
            out.append(None)
    return out


def weighted_linear_parameters(model: Model, partition: Partition, data: Dataset, xi2, R) -> np.ndarray:
    """xi1 = argmin sum_k ||z_k - A_k xi1 - b_k||^2_{R^-1} by QR (paper Eq. 27), shape (n1,)."""
    from .stage1 import batched_least_squares

    if partition.n_linear == 0:
        return np.zeros(0)
    N, ny = data.n_samples, model.n_outputs
    xi2 = np.asarray(xi2, dtype=float)
    (A,) = evaluate(partition.A.map("A_all", "serial", N, [1], []), data.signals.T, xi2)
    (b,) = evaluate(partition.b.map("b_all", "serial", N, [1], []), data.signals.T, xi2)
    A = A.reshape(ny, N, -1).transpose(1, 0, 2)
    b = b.reshape(ny, N).T
    w = data.output_mask() / np.sqrt(np.asarray(R, dtype=float).reshape(1, ny))  # rows not measured: weight 0
    Aw = (A * w[:, :, None]).reshape(1, N * ny, -1)
    yw = ((data.filled_outputs() - b) * w).reshape(1, N * ny)
    x, ok = batched_least_squares(Aw, yw)
    if not ok[0]:
        from .stage1 import IdentifiabilityError

        raise IdentifiabilityError(
            f"A(xi2) is rank-deficient at xi2 = {np.asarray(xi2).tolist()}: the linear "
            f"parameters {list(partition.linear)} cannot be separated by these data"
        )
    return x[0]


# ----------------------------------------------------------------------------- solve
def _check_start(model: Model, theta0: np.ndarray) -> None:
    lb, ub = model.lower_bounds, model.upper_bounds
    bad = [
        f"{n} = {t:g} not in [{lo:g}, {hi:g}]"
        for n, t, lo, hi in zip(model.parameter_names, theta0, lb, ub)
        if not (lo <= t <= hi)
    ]
    if bad:
        raise OptionError(
            "the start lies outside the parameter bounds: " + "; ".join(bad) + ". Move the "
            "start inside the bounds or widen them"
        )
    if not np.all(np.isfinite(theta0)):
        raise OptionError(f"the start has non-finite values: {theta0.tolist()}")


def _run(problem: _Problem, w0, lbw, ubw, p, settings: SolverSettings) -> tuple[np.ndarray, str, bool, int, list]:
    """Solve, and accept a short-of-tolerance stop only at a verified stationary point."""
    w, stats = problem.solve(w0, lbw, ubw, p, settings.max_iter)
    status = str(stats.get("return_status", "unknown"))
    success = bool(stats.get("success", False))
    notes = []
    if not success and status in _ACCEPTABLE_STATUSES and np.all(np.isfinite(w)):
        grad, hess = evaluate(problem.newton, w, p)
        span = np.maximum(1.0, np.abs(w))
        at_bound = (np.abs(w - lbw) <= 1e-8 * span) | (np.abs(w - ubw) <= 1e-8 * span)
        free = ~at_bound
        Hf = hess[np.ix_(free, free)]
        try:
            np.linalg.cholesky(Hf)
            step = np.linalg.solve(Hf, -grad[free])
            if np.linalg.norm(step, np.inf) < settings.newton_acceptance:
                success = True
                notes.append(Note(
                    f"IPOPT stopped with {status}; accepted because the exact Newton step there is "
                    f"{np.linalg.norm(step, np.inf):.1e} (scaled units) and the Hessian is positive definite",
                    NoteCode.ACCEPTED))
        except np.linalg.LinAlgError:
            pass
    return w, status, success, int(stats.get("iter_count", 0)), notes


def solve_stage2(
    model: Model,
    data: Dataset,
    theta0,
    partition: Partition | None = None,
    mode: str = "full",
    settings: SolverSettings | None = None,
    R0=None,
    known_R=None,
    prior_penalty: bool = False,
    full_R: bool = False,
) -> Stage2Result:
    """Minimise the ML cost of Eq. 6 over theta and the diagonal R with IPOPT.

    Parameters
    ----------
    model : Model
    data : Dataset
    theta0 : array_like, shape (n_parameters,) or mapping
        Start (physical units); must lie inside the bounds. In ``reduced`` and
        ``alternating`` mode only its xi2 part is used.
    partition : Partition, optional
        Default :func:`casest.separate` of the model.
    mode : {"full", "reduced", "alternating"}
    settings : SolverSettings, optional
    R0 : array_like, shape (n_outputs,), optional
        Start of R; default: the residual mean square at ``theta0``.
    known_R : array_like, shape (n_outputs,), optional
        Known noise variances: R is held at them (no ln|R| term to estimate), so the
        solution is the weighted least squares with weights 1/R.
    prior_penalty : bool
        Add the parameters' Gaussian priors to the cost as ``(theta - mean)^2 / (2 std^2)``
        (MAP; full mode, which is used whatever ``mode`` says). ``cost`` then includes them.
    full_R : bool
        R full and unknown (correlated channels), log-Cholesky parametrised, estimated with
        theta in full mode; ``R_full`` of the result holds it, ``R`` its diagonal.

    Returns
    -------
    Stage2Result
    """
    from .separate import separate

    t0 = time.perf_counter()
    if mode not in MODES:
        raise OptionError(f"mode must be one of {MODES}, got {mode!r}")
    settings = settings or SolverSettings()
    data.check_model(model)
    partition = partition or separate(model)
    theta0 = model.vector(theta0)
    _check_start(model, theta0)
    N = data.n_samples
    p = data_vector(data)
    floor = noise_floor(data, settings)
    if full_R:
        return _solve_full_noise(model, data, theta0, partition, settings, p, floor, prior_penalty, t0)
    if known_R is not None:
        known_R = np.asarray(known_R, dtype=float).reshape(-1)
        if known_R.size != model.n_outputs or not np.all(np.isfinite(known_R) & (known_R > 0)):
            raise OptionError(f"known_R needs {model.n_outputs} positive finite variances, got {known_R.tolist()}")
        if mode == "alternating":
            mode = "reduced"  # with R known there is nothing to alternate
    notes: list[str] = []
    penalty = None
    if prior_penalty:
        penalty = model.gaussian_prior_terms()
        if mode != "full":
            notes.append(Note(f"Gaussian priors as penalties: stage 2 in full mode instead of {mode}", NoteCode.NOISE_MODEL))
            mode = "full"
    start_cost, R0 = start_point(model, data, theta0, floor, R0, known_R, penalty)
    if known_R is not None:
        lo_rho = hi_rho = np.log(R0)  # R held: IPOPT treats equal bounds as fixed
    else:
        lo_rho, hi_rho = np.log(floor), np.full(model.n_outputs, np.inf)

    if mode == "full":
        problem = _problem(model, partition, N, "full", settings, penalty, data.has_missing)
        w0 = np.concatenate([theta0 / problem.scale, np.log(R0)])
        lbw = np.concatenate([model.lower_bounds / problem.scale, lo_rho])
        ubw = np.concatenate([model.upper_bounds / problem.scale, hi_rho])
        w, status, success, iters, run_notes = _run(problem, w0, lbw, ubw, p, settings)
        notes += run_notes
        (theta,) = evaluate(problem.theta_of, w, p)
        R = np.exp(w[problem.n_s :])
        used_mode = "full"
    else:
        problem = _problem(model, partition, N, "reduced", settings, None, data.has_missing)
        idx2 = list(partition.nonlinear_index)
        lb2, ub2 = model.lower_bounds[idx2], model.upper_bounds[idx2]
        s0 = theta0[idx2] / problem.scale
        lbs, ubs = lb2 / problem.scale, ub2 / problem.scale
        if mode == "reduced":
            w0 = np.concatenate([s0, np.log(R0)])
            lbw = np.concatenate([lbs, lo_rho])
            ubw = np.concatenate([ubs, hi_rho])
            w, status, success, iters, run_notes = _run(problem, w0, lbw, ubw, p, settings)
            notes += run_notes
            R = np.exp(w[problem.n_s :])
        else:
            w, R, status, success, iters, loop_notes = _alternate(problem, s0, lbs, ubs, R0, floor, p, model, data, partition, settings)
            notes += loop_notes
        xi2 = w[: problem.n_s] * problem.scale
        xi1 = weighted_linear_parameters(model, partition, data, xi2, R)
        theta = partition.assemble(xi1, xi2)
        used_mode = mode
        lin_idx = list(partition.linear_index)
        lb1, ub1 = model.lower_bounds[lin_idx], model.upper_bounds[lin_idx]
        violated = [n for n, v, lo, hi in zip(partition.linear, xi1, lb1, ub1) if not lo <= v <= hi]
        if violated:
            notes.append(Note(
                f"{mode} stage 2 put linear parameter(s) {violated} outside their bounds; "
                "re-solved in full mode from that point with them clipped to the bounds", NoteCode.BOUNDS))
            start = np.clip(theta, model.lower_bounds, model.upper_bounds)
            inner = solve_stage2(model, data, start, partition, "full", settings, R0=R, known_R=known_R,
                                 prior_penalty=prior_penalty)
            inner.notes = notes + inner.notes
            inner.n_iterations += iters
            inner.seconds = time.perf_counter() - t0
            return inner
    # IPOPT may end a hair outside a bound through rounding; the result must respect them
    theta = np.clip(theta, model.lower_bounds, model.upper_bounds)
    outcome = Outcome.ACCEPTED_NEWTON if success and any(note_code(n) is NoteCode.ACCEPTED for n in notes) else None
    if known_R is not None:
        R = R0.copy()  # exactly the given variances (not exp(log(R)))
    if not success and known_R is None:
        exact, R_exact, note = _exact_fit(model, data, theta, floor, settings)
        if exact:
            success, R = True, R_exact
            notes.append(Note(f"IPOPT stopped with {status}; " + note, NoteCode.ACCEPTED))
            outcome = Outcome.EXACT_FIT
    cost = ml_cost(model, data, theta, R) + prior_penalty_value(penalty, theta)
    if success and cost > start_cost + 1e-9 * max(1.0, abs(start_cost)):
        # a converged solve above its start is a stationary point it climbed to (a plateau
        # or saddle), not an improvement: never reported as a success
        success, status, outcome = False, "Climbed", Outcome.CLIMBED
        notes.append(Note(f"stage 2 ({used_mode}) ended at J = {cost:.10g}, above its start's J = {start_cost:.10g}: "
                     "it stopped on a plateau or saddle; the start is better", NoteCode.CLIMBED))
    if outcome is None:
        outcome = Outcome.CONVERGED if success else Outcome.NOT_CONVERGED
    message = ("converged" if success else "ended above the cost of its start" if status == "Climbed"
               else f"IPOPT did not converge ({status})")
    at_floor = [c for c, r, f in zip(model.output_names, R, floor) if r <= f * (1 + 1e-6)] if known_R is None else []
    if at_floor:
        notes.append(Note(
            f"noise variance of {at_floor} is at the floor ({settings.noise_floor:g} x mean square): "
            "the model fits these data (almost) exactly, so R is not determined", NoteCode.NOISE_FLOOR))
    return Stage2Result(
        theta=theta,
        R=R,
        cost=cost,
        success=success,
        status=status,
        message=message,
        n_iterations=iters,
        mode=used_mode,
        notes=notes,
        seconds=time.perf_counter() - t0,
        outcome=outcome,
    )


def full_noise_cost(model: Model, data: Dataset, theta, R_full) -> float:
    """Paper Eq. 6 with a full noise covariance: ``1/2 sum_k r_k' R^-1 r_k + N/2 ln|R|``."""
    resid = data.outputs - model.predict(model.vector(theta), data.signals)
    L = np.linalg.cholesky(np.asarray(R_full, dtype=float))
    y = np.linalg.solve(L, resid.T)
    return float(0.5 * np.sum(y**2) + data.n_samples * np.sum(np.log(np.diag(L))))


def cholesky_vector(R_full: np.ndarray) -> np.ndarray:
    """The log-Cholesky vector of a covariance (see :func:`casest.sums.cholesky_factor`)."""
    L = np.linalg.cholesky(R_full)
    ny = L.shape[0]
    return np.concatenate([np.log(np.diag(L))] + [L[j + 1:, j] for j in range(ny)])


def covariance_of(ell: np.ndarray, ny: int) -> np.ndarray:
    """The covariance L L' of a log-Cholesky vector."""
    from .sums import cholesky_factor

    L = np.asarray(ca.evalf(cholesky_factor(ca.SX(ell), ny)))
    return L @ L.T


def _solve_full_noise(model, data, theta0, partition, settings, p, floor, prior_penalty, t0) -> Stage2Result:
    """Stage 2 with R full and unknown: theta and the log-Cholesky factor of R, in full mode."""
    if data.has_missing:
        raise DataError("a full unknown R needs complete data (every output at every sample); drop the "
                        "samples with missing outputs or use the diagonal R")
    ny, N = model.n_outputs, data.n_samples
    penalty = model.gaussian_prior_terms() if prior_penalty else None
    start_cost, S0 = start_point(model, data, theta0, floor, penalty=penalty, full_R=True)
    problem = _problem(model, partition, N, "full", settings, penalty, False, True)
    ell0 = cholesky_vector(S0)
    w0 = np.concatenate([theta0 / problem.scale, ell0])
    lo_ell = np.concatenate([0.5 * np.log(floor), np.full(len(ell0) - ny, -np.inf)])
    lbw = np.concatenate([model.lower_bounds / problem.scale, lo_ell])
    ubw = np.concatenate([model.upper_bounds / problem.scale, np.full(len(ell0), np.inf)])
    w, status, success, iters, notes = _run(problem, w0, lbw, ubw, p, settings)
    (theta,) = evaluate(problem.theta_of, w, p)
    theta = np.clip(theta, model.lower_bounds, model.upper_bounds)
    R_full = covariance_of(w[problem.n_s:], ny)
    cost = full_noise_cost(model, data, theta, R_full) + prior_penalty_value(penalty, theta)
    outcome = Outcome.ACCEPTED_NEWTON if success and notes else (Outcome.CONVERGED if success else Outcome.NOT_CONVERGED)
    if success and cost > start_cost + 1e-9 * max(1.0, abs(start_cost)):
        success, status, outcome = False, "Climbed", Outcome.CLIMBED
        notes.append(Note(f"stage 2 (full R) ended at J = {cost:.10g}, above its start's J = {start_cost:.10g}",
                          NoteCode.CLIMBED))
    result = Stage2Result(theta=theta, R=np.diag(R_full).copy(), cost=cost, success=success, status=status,
                          message="converged" if success else f"IPOPT did not converge ({status})", n_iterations=iters,
                          mode="full", notes=notes, seconds=time.perf_counter() - t0, outcome=outcome)
    result.R_full = R_full
    return result


def _exact_fit(model: Model, data: Dataset, theta: np.ndarray, floor: np.ndarray, settings: SolverSettings):
    """Recognise an exact fit (every R_j at the floor) at a least-squares point.

    With data that the model reproduces exactly the likelihood has no maximum
    (R -> 0); IPOPT then stalls on round-off amplified by the weights 1/R. The point
    is accepted when the residual mean square is below the floor in every channel and a
    Gauss-Newton step on the free parameters is shorter than ``newton_acceptance``
    (in units of the parameters' scales).
    """
    from .sums import residual_jacobian

    resid = np.nan_to_num(data.outputs - model.predict(theta, data.signals))  # 0 where not measured
    ms = residual_mean_square(model, data, theta)
    if np.any(ms > floor):
        return False, None, ""
    active = active_bounds(theta, model.lower_bounds, model.upper_bounds, model.scales)
    free = [i for i, a in enumerate(active) if a is None]
    J = residual_jacobian(model, data, theta)[:, free] * model.scales[free]
    J = J * data.output_mask().reshape(-1)[:, None]
    step, *_ = np.linalg.lstsq(J, resid.reshape(-1), rcond=None)
    size = float(np.max(np.abs(step))) if step.size else 0.0
    if size >= settings.newton_acceptance:
        return False, None, ""
    return True, floor.copy(), (
        f"the data are fitted exactly (residual mean square below the noise floor); accepted "
        f"because a Gauss-Newton step there is {size:.1e} (scaled units)"
    )


def _alternate(problem, s0, lbs, ubs, R0, floor, p, model, data, partition, settings):
    """Paper Eq. 26: xi2 with R fixed, then R from the residuals, until R settles."""
    R = R0.copy()
    s = s0.copy()
    iters = 0
    notes: list[str] = []
    status, success = "Maximum_Alternations_Exceeded", False
    for k in range(settings.max_alternations):
        rho = np.log(R)
        w0 = np.concatenate([s, rho])
        lbw = np.concatenate([lbs, rho])
        ubw = np.concatenate([ubs, rho])
        w, ipopt_status, ok, it, run_notes = _run(problem, w0, lbw, ubw, p, settings)
        iters += it
        if not ok:
            return w, R, ipopt_status, False, iters, notes + run_notes
        s = w[: problem.n_s]
        (theta,) = evaluate(problem.theta_of, w, p)
        R_new = np.maximum(residual_mean_square(model, data, theta), floor)
        change = np.abs(R_new - R) / R_new
        R = R_new
        if np.all(change < settings.alternating_tol):
            status, success = "Solve_Succeeded", True
            notes.append(Note(f"alternating loop: R settled within {settings.alternating_tol:.0%} after {k + 1} passes"))
            break
    w = np.concatenate([s, np.log(R)])
    return w, R, status, success, iters, notes
