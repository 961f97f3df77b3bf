"""The one IPOPT path: settings, options, how a run ends, the bound rule and the noise floor.

Every IPOPT solve in casest (stage 2, filter-error ML, experiment and input design, the
paper's baselines, the embedding) takes its options from :class:`SolverSettings`, reads
its outcome with :func:`run_ipopt`, decides "on a bound" with :func:`active_bounds` and
bounds noise variances with :func:`noise_floor`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import casadi as ca
import numpy as np

from ..options import LeastSquaresSolver, OutputErrorSolver, Shooting, check_option, choices
from ..errors import OptionError
from ..checks import whole_number


__all__ = ["SolverSettings", "ACCEPTABLE_STATUSES", "IpoptRun", "run_ipopt", "active_bounds", "noise_floor",
           "newton_step_accepts", "IterateRecorder"]


#: IPOPT stops short of its tolerance that the exact Newton check may still accept
ACCEPTABLE_STATUSES = (
    "Solved_To_Acceptable_Level",
    "Search_Direction_Becomes_Too_Small",
    "Restoration_Failed",
    "Error_In_Step_Computation",
    "Maximum_Iterations_Exceeded",
)


OUTPUT_ERROR_SOLVERS = choices(OutputErrorSolver)
LEAST_SQUARES_SOLVERS = choices(LeastSquaresSolver)


@dataclass(frozen=True)
class SolverSettings:
    """Settings of casest's IPOPT solves (stage 2, filter error, experiment design, baselines, embedding).

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
    shooting : {"single", "multiple"}
        Output error of a dynamic model: simulate the whole record from the initial state
        (single), or from state nodes every ``shooting_interval`` samples that are decision
        variables tied by continuity constraints (multiple; for long or unstable records:
        a poor start cannot make the simulation diverge). Multiple shooting uses CasADi's
        exact Hessian of the Lagrangian.
    shooting_interval : int
        Samples per shooting interval.
    output_error_solver : {"auto", "gauss-newton", "ipopt"}
        Stage 2 of a dynamic model by single shooting with a diagonal R:
        ``"gauss-newton"`` (bounded Gauss-Newton / Levenberg-Marquardt with first-order
        sensitivities, as flight-test tools do; :mod:`casest.estimation.gauss_newton`)
        or ``"ipopt"`` (IPOPT with the exact Hessian: :mod:`casest.backend.second_order`).
        Both reach the same optimum. ``"auto"``: Gauss-Newton where it applies (it needs
        only first derivatives, so it builds in seconds where the exact Hessian of a big
        model takes far longer to evaluate per iteration), IPOPT otherwise (multiple
        shooting, CVODES models, a full R).
    least_squares_solver : {"auto", "levenberg-marquardt", "ipopt"}
        Stage 2 of a static model in full mode with a diagonal R and no priors as penalties:
        ``"levenberg-marquardt"`` (casest's Levenberg-Marquardt on the (reweighted) least
        squares, exact CasADi Jacobian, bounds mapped as in MINUIT and lmfit; the point is
        accepted when the Gauss-Newton decrement there is below 1e-12, otherwise IPOPT solves
        from the start with the same budget; :mod:`casest.two_stage.solve.levenberg_marquardt`)
        or ``"ipopt"``. Both reach the same optimum; Levenberg-Marquardt costs tens of
        microseconds an iteration on small problems. ``"auto"``: Levenberg-Marquardt where it
        applies and the problem has at most 1000 residuals (N times the outputs; beyond,
        IPOPT's compiled sums are faster).
    record_iterates : bool
        Record stage 2's iterates in ``Estimate.convergence`` on the IPOPT paths too (a
        Python call per IPOPT iteration; the Gauss-Newton output-error solver always
        records them, Levenberg-Marquardt never).
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
    shooting: Shooting = "single"
    shooting_interval: int = 200
    output_error_solver: OutputErrorSolver = "auto"
    least_squares_solver: LeastSquaresSolver = "auto"
    record_iterates: bool = False

    def __post_init__(self):
        for name, low in (("tol", 0.0), ("noise_floor", 0.0), ("alternating_tol", 0.0), ("newton_acceptance", 0.0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                    or not np.isfinite(value) or value <= low:
                raise OptionError(f"SolverSettings.{name} must be a positive finite number, got {value!r}")
        for name, low in (("max_iter", 0), ("start_max_iter", 1), ("max_alternations", 1), ("jit_min_samples", 0)):
            value = getattr(self, name)
            whole_number(value, f"SolverSettings.{name} must be an integer >= {low}", low)
        check_option("SolverSettings.shooting", self.shooting, Shooting)
        check_option("SolverSettings.output_error_solver", self.output_error_solver, OutputErrorSolver)
        check_option("SolverSettings.least_squares_solver", self.least_squares_solver, LeastSquaresSolver)
        whole_number(self.shooting_interval, "SolverSettings.shooting_interval must be a positive integer")

    def resolved_jit(self, n_samples: int) -> bool:
        """Whether sums over ``n_samples`` are compiled (see ``jit``).

        Parameters
        ----------
        n_samples : int

        Returns
        -------
        bool
        """
        if self.jit is None:
            from .._casadi.numerics import compiler_available

            return n_samples >= self.jit_min_samples and compiler_available()
        return bool(self.jit)

    def record_loop(self, n_samples: int) -> bool | None:
        """Whether a recursion over a record of ``n_samples`` runs as one compiled C loop: True
        (compile it now), None (only where it is compiled already, in this process or the compile
        cache: a short record costs no compile, and runs compiled once a longer one compiled
        it), False (never: ``jit=False``).

        Parameters
        ----------
        n_samples : int

        Returns
        -------
        bool or None
        """
        if self.jit is None:
            return True if self.resolved_jit(n_samples) else None
        return bool(self.jit)

    def resolved_threads(self, n_samples: int) -> int:
        """Threads for sums over ``n_samples`` (see ``threads``).

        Parameters
        ----------
        n_samples : int

        Returns
        -------
        int
        """
        from .._casadi.numerics import default_threads

        return default_threads(n_samples) if self.threads is None else max(1, int(self.threads))

    def nlpsol_options(self) -> dict:
        """The options of ``casadi.nlpsol(..., "ipopt", ...)``: casest's defaults, then ``ipopt``.

        Returns
        -------
        dict
        """
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

    def sqpmethod_options(self) -> dict:
        """The options of ``casadi.nlpsol(..., "sqpmethod", ...)`` with the ``qrqp`` QP solver (a
        solver CasADi can generate as C): the same iteration budget and tolerance as IPOPT's,
        silent, and a failed solve reported through the return status instead of an exception.

        Returns
        -------
        dict
        """
        return {"qpsol": "qrqp", "qpsol_options": {"print_iter": False, "print_header": False, "error_on_fail": False},
                "max_iter": self.max_iter, "tol_pr": self.tol, "tol_du": self.tol, "print_header": False,
                "print_iteration": False, "print_status": False, "print_time": False, "error_on_fail": False}


def noise_floor(data, settings: SolverSettings) -> np.ndarray:
    """Lower bound of each noise variance R_j in stage 2.

    Parameters
    ----------
    data : Dataset
    settings : SolverSettings
        Its relative noise floor.

    Returns
    -------
    ndarray, shape (n_outputs,)
        Unit of each output squared.
    """
    ms = data.output_mean_square()
    return settings.noise_floor * np.where(ms > 0, ms, 1.0)


def active_bounds(theta: np.ndarray, lb: np.ndarray, ub: np.ndarray, scale: np.ndarray, tol: float = 1e-7) -> list:
    """Which parameters lie on a bound: the one rule for "on a bound".

    Parameters
    ----------
    theta, lb, ub, scale : ndarray, shape (n,)
        Values, bounds and scales (physical units).
    tol : float
        Distance counted as on the bound, in scaled units (infinite bounds are never active).

    Returns
    -------
    list
        Per parameter ``"lower"``, ``"upper"`` or None.
    """
    out = []
    for t, lo, hi, s in zip(theta, lb, ub, scale):
        if np.isfinite(lo) and abs(t - lo) <= tol * max(s, abs(lo)):
            out.append("lower")
        elif np.isfinite(hi) and abs(t - hi) <= tol * max(s, abs(hi)):
            out.append("upper")
        else:
            out.append(None)
    return out


@dataclass(frozen=True)
class IpoptRun:
    """How one IPOPT solve ended.

    Attributes
    ----------
    x : ndarray, shape (n_x,)
        The last iterate.
    f : float
        The objective there.
    status : str
        IPOPT's return status.
    success : bool
        IPOPT converged to its tolerance.
    iterations : int
    """

    x: np.ndarray
    f: float
    status: str
    success: bool
    iterations: int


def run_ipopt(solver, **arguments) -> IpoptRun:
    """Call a ``casadi.nlpsol`` IPOPT solver and read its outcome the one way.

    Parameters
    ----------
    solver : casadi.Function
        An ``nlpsol`` with the IPOPT plugin.
    **arguments
        Its inputs (``x0``, ``p``, ``lbx``, ``ubx``, ...).

    Returns
    -------
    IpoptRun
        The solution, the return status, whether it is acceptable, and the iterations.
    """
    solution = solver(**arguments)
    stats = solver.stats()
    return IpoptRun(x=np.asarray(solution["x"], dtype=float).reshape(-1), f=float(solution["f"]),
                    status=str(stats.get("return_status", "unknown")), success=bool(stats.get("success", False)),
                    iterations=int(stats.get("iter_count", 0)))


def newton_step_accepts(gradient: np.ndarray, hessian: np.ndarray, free: np.ndarray, acceptance: float) -> float | None:
    """The test that accepts an IPOPT stop short of its tolerance at a verified stationary point.

    Parameters
    ----------
    gradient : ndarray, shape (n,)
    hessian : ndarray, shape (n, n)
    free : ndarray of bool, shape (n,)
        The variables not on a bound.
    acceptance : float
        Largest accepted step (inf-norm, scaled units).

    Returns
    -------
    float or None
        The length of the exact Newton step on the free variables when the Hessian there is
        positive definite and the step is below ``acceptance``; else None.
    """
    try:
        Hf = hessian[np.ix_(free, free)]
        np.linalg.cholesky(Hf)
        step = float(np.linalg.norm(np.linalg.solve(Hf, -gradient[free]), np.inf))
    except np.linalg.LinAlgError:
        return None
    return step if step < acceptance else None


class IterateRecorder(ca.Callback):
    """An IPOPT ``iteration_callback`` that keeps each iterate's decision vector and objective.

    Parameters
    ----------
    n_variables, n_constraints : int
        Sizes of the NLP's x and g.
    """

    def __init__(self, n_variables: int, n_constraints: int = 0):
        ca.Callback.__init__(self)
        self.n_variables, self.n_constraints = int(n_variables), int(n_constraints)
        self.iterates: list = []
        self.construct("casest_iterates", {})

    def clear(self) -> None:
        """Forget the iterates of an earlier solve."""
        self.iterates = []

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.n_variables)
        if name in ("g", "lam_g"):
            return ca.Sparsity.dense(self.n_constraints)
        return ca.Sparsity(0, 0)

    def eval(self, arg):
        self.iterates.append((np.array(arg[0], dtype=float).reshape(-1), float(arg[1])))
        return [0]
