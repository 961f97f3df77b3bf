"""The exact minimiser of a convex quadratic under linear inequalities, ``min 1/2 d' M d + g' d
s.t. A d <= b``, for filter error's constrained Gauss-Newton step, with feasibility judged
relative to each row's terms whatever the problem's units.

Three stages, each checked before its answer is taken:

1. the least-distance programme by non-negative least squares (Lawson and Hanson, *Solving
   Least Squares Problems*, Ch. 23) on the Jacobi-scaled problem, which gives the active rows;
2. the KKT system on those rows solved exactly (:func:`_on_active_rows`): a bound row fixes its
   unknown outright, so a step lands on a bound bit for bit; the answer is kept when every row
   is met to :data:`FEASIBILITY_TOLERANCE` of its terms and every multiplier is non-negative;
3. otherwise, and where NNLS finds no step, HiGHS's quadratic programme (through CasADi, rows of
   unit norm) decides whether a step exists, and its active rows are solved as in 2.

None is returned where no step meets every row: NNLS alone decides feasibility on an absolute
residual and gave steps to infeasible problems that broke a row by hundreds of its size.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import nnls

__all__ = ["least_distance_step", "relative_violation", "FEASIBILITY_TOLERANCE"]

#: a step meets a row ``a' d <= beta`` when ``a' d - beta <= FEASIBILITY_TOLERANCE (|a|'|d| + |beta|)``:
#: rounding relative to the row's terms, whatever the problem's units
FEASIBILITY_TOLERANCE = 1e-9
#: a multiplier counts as negative (the row should not be active) below this fraction of the largest
_MULTIPLIER_FLOOR = 1e-9
#: HiGHS QP solvers built per problem size ``(n, m)``
_HIGHS: dict = {}


def least_distance_step(M: np.ndarray, g: np.ndarray, A: np.ndarray, b: np.ndarray,
                        b_scale: np.ndarray | None = None) -> tuple:
    """The exact minimiser of ``1/2 d' M d + g' d`` subject to ``A d <= b``.

    Parameters
    ----------
    M : ndarray, shape (n, n)
        Symmetric positive definite.
    g : ndarray, shape (n,)
    A : ndarray, shape (m, n)
    b : ndarray, shape (m,)
    b_scale : ndarray, shape (m,), optional
        The size of the terms each ``b`` was computed from (``|b|`` when omitted): ``1 - k`` carries
        the rounding of 1 however small it is.

    Returns
    -------
    d : ndarray, shape (n,) or None
        None where no ``d`` meets every row to :data:`FEASIBILITY_TOLERANCE` of its terms.
    multipliers : ndarray, shape (m,)
        Non-negative; positive on the rows active at ``d`` (zeros where ``d`` is None).
    """
    m, n = A.shape
    # Jacobi scaling d = z / D (parameters whose curvatures differ by decades take the same
    # relative accuracy) and 1e-13 on the scaled diagonal (a parameter the data do not see)
    diagonal = np.abs(np.diag(M))
    D = np.sqrt(np.maximum(diagonal, 1e-300 + 1e-30 * float(np.max(diagonal, initial=0.0))))
    scaled = (M / np.outer(D, D) + 1e-13 * np.eye(n), g / D, A / D[None, :], b)
    if m == 0:
        return np.linalg.solve(scaled[0], -scaled[1]) / D, np.zeros(0)
    # HiGHS only where NNLS's rows do not give a step, on the unscaled problem (its QP failed on
    # Jacobi-scaled ones with costs of 1e3 against right-hand sides of 1e-5)
    for find_rows in (lambda: _nnls_active_rows(*scaled), lambda: _highs_active_rows(M, g, A, b)):
        active = find_rows()
        if active is None:
            continue
        z, multipliers = _on_active_rows(*scaled, active)
        if z is None:
            continue
        d = z / D
        rows, unknowns = _active_bounds(A, active)
        d[unknowns] = b[rows] / A[rows, unknowns]  # on a bound bit for bit (z / D rounds)
        if np.max(relative_violation(A, b, d, b_scale)) <= FEASIBILITY_TOLERANCE:
            return d, multipliers
    return None, np.zeros(m)


def relative_violation(A: np.ndarray, b: np.ndarray, d: np.ndarray, b_scale: np.ndarray | None = None) -> np.ndarray:
    """How far ``d`` breaks each row of ``A d <= b``, relative to the row's terms.

    Parameters
    ----------
    A : ndarray, shape (m, n)
    b : ndarray, shape (m,)
    d : ndarray, shape (n,)
    b_scale : ndarray, shape (m,), optional
        The size of the terms ``b`` was computed from (default ``|b|``).

    Returns
    -------
    ndarray, shape (m,)
        ``(A d - b) / (|A| |d| + max(|b|, b_scale))`` (the row's own value where that is 0);
        positive where a row is broken.
    """
    scale = np.abs(A) @ np.abs(d) + (np.abs(b) if b_scale is None else np.maximum(np.abs(b), b_scale))
    return (A @ d - b) / np.where(scale > 0.0, scale, 1.0)


def _nnls_active_rows(M: np.ndarray, g: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """The rows NNLS's least-distance solution holds active (positive multipliers); None where
    NNLS finds the rows infeasible.

    With ``M = L L'`` and ``y = L' d + L^-1 g`` the problem is ``min ||y|| s.t. G y <= h``
    (``G = A L'^-1``, ``h = b + G L^-1 g``, in rows of unit norm), whose solution is the residual of
    one NNLS."""
    n = g.size
    L = np.linalg.cholesky(M)
    Li_g = solve_triangular(L, g, lower=True)
    G = solve_triangular(L, A.T, lower=True).T
    norms = np.maximum(np.linalg.norm(G, axis=1), 1e-300)
    G, h = G / norms[:, None], (b + G @ Li_g) / norms
    # y in units of max |h|: a solution far from the origin (||y|| >> 1) would leave NNLS's
    # residual r[-1] ~ -1 / (1 + ||y||^2) below any fixed threshold
    h = h / max(float(np.max(np.abs(h))), 1e-300)
    stacked = np.vstack([-G.T, -h[None, :]])  # (n + 1, m): min ||y|| s.t. -G y >= -h
    target = np.zeros(n + 1)
    target[-1] = 1.0
    u, _ = nnls(stacked, target, maxiter=50 * (n + A.shape[0]))
    r = stacked @ u - target
    return u > 0.0 if r[-1] < -1e-12 else None


def _highs_active_rows(M: np.ndarray, g: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """The rows HiGHS's QP solution holds active; None where HiGHS finds the rows infeasible or fails."""
    n, m = g.size, b.size
    if (n, m) not in _HIGHS:
        _HIGHS[n, m] = ca.conic("least_distance", "highs", {"h": ca.Sparsity.dense(n, n), "a": ca.Sparsity.dense(m, n)},
                                {"error_on_fail": False,
                                 # an iteration cap: HiGHS's QP can cycle on an infeasible problem (seen:
                                 # 3 unknowns, 9 rows, no end); one thread: no idle workers spinning
                                 "highs": {"output_flag": False, "qp_iteration_limit": 100 * (n + m),
                                           "time_limit": 10.0, "threads": 1}})
    solver, norms = _HIGHS[n, m], np.maximum(np.linalg.norm(A, axis=1), 1e-300)
    size = max(float(np.max(np.abs(np.diag(M)))), 1e-300)
    solution = solver(h=M / size, g=g / size, a=A / norms[:, None], lba=-np.inf, uba=b / norms, lbx=-np.inf,
                      ubx=np.inf)
    if not solver.stats()["success"]:
        return None
    return np.asarray(solution["lam_a"]).reshape(-1) > 0.0


def _dependent(rows: np.ndarray) -> bool:
    """Whether ``rows`` (each scaled to unit norm) are linearly dependent to within 1e-10 of their
    largest singular value (a pair ``a``, ``-a`` of a contradiction, or a repeated row)."""
    unit = rows / np.maximum(np.linalg.norm(rows, axis=1), 1e-300)[:, None]
    singular = np.linalg.svd(unit, compute_uv=False)
    return bool(singular.size < rows.shape[0] or singular[-1] <= 1e-10 * singular[0])


def _active_bounds(A: np.ndarray, active: np.ndarray) -> tuple:
    """The active rows on one unknown (bounds) and the unknown each fixes."""
    rows = np.flatnonzero(active & (np.count_nonzero(A, axis=1) == 1))
    return rows, np.argmax(A[rows] != 0, axis=1)


def _on_active_rows(M: np.ndarray, g: np.ndarray, A: np.ndarray, b: np.ndarray, active: np.ndarray) -> tuple:
    """The minimiser with the ``active`` rows held as equalities and their multipliers, by the KKT
    system; a row on one unknown (a bound) fixes it outright. ``(None, None)`` where the active
    rows are dependent (the KKT system is singular) or a multiplier is negative (the active set is
    not the optimum's)."""
    n = g.size
    single = np.count_nonzero(A, axis=1) == 1
    fixed_rows, fixed = _active_bounds(A, active)
    if np.unique(fixed).size < fixed.size:
        return None, None  # two bounds of one unknown both active
    d = np.zeros(n)
    d[fixed] = b[fixed_rows] / A[fixed_rows, fixed]
    free = np.setdiff1d(np.arange(n), fixed)
    general = np.flatnonzero(active & ~single)
    Af = A[np.ix_(general, free)]
    if general.size > free.size or (general.size and _dependent(Af)):
        return None, None  # more active rows than unknowns, or rows that contradict or repeat
    kkt = np.block([[M[np.ix_(free, free)], Af.T], [Af, np.zeros((general.size, general.size))]])
    rhs = np.concatenate([-(g[free] + M[np.ix_(free, fixed)] @ d[fixed]), b[general] - A[np.ix_(general, fixed)] @ d[fixed]])
    try:
        solution = np.linalg.solve(kkt, rhs)
        for _ in range(2):  # iterative refinement: the active rows met to their rounding
            solution = solution + np.linalg.solve(kkt, rhs - kkt @ solution)
    except np.linalg.LinAlgError:
        return None, None
    if not np.all(np.isfinite(solution)):
        return None, None
    d[free] = solution[:free.size]
    multipliers = np.zeros(A.shape[0])
    multipliers[general] = solution[free.size:]
    # each fixed unknown's multiplier from its stationarity row: (M d + g + A' lambda)_j = 0
    residual = M @ d + g + A.T @ multipliers
    multipliers[fixed_rows] = -residual[fixed] / A[fixed_rows, fixed]
    if np.min(multipliers, initial=0.0) < -_MULTIPLIER_FLOOR * max(float(np.max(np.abs(multipliers), initial=0.0)), 1e-300):
        return None, None
    return d, np.maximum(multipliers, 0.0)
