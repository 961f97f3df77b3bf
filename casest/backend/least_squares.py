"""The linear least squares of stage 1, batched over candidates: normal equations with a QR
fallback for ill-conditioned bases, and box-constrained solves for bounded xi1."""

from __future__ import annotations

import numpy as np


__all__ = ["batched_least_squares", "refined_least_squares", "box_least_squares", "feasible_solutions",
           "condition_below"]

#: the Cholesky bound decides a matrix alone when it is this many times below the limit (the bound's
#: and eigvalsh's rounding are ~n eps cond, far inside); limits above SCREENED_LIMIT go to eigvalsh
SCREEN_MARGIN, SCREENED_LIMIT = 4.0, 1e12


def batched_least_squares(
    A: np.ndarray, y: np.ndarray, rcond: float = 1e-11, without_q: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``min ||A_m x - y_m||`` for a stack of problems by column-scaled QR.

    Parameters
    ----------
    A : ndarray, shape (M, K, n)
    y : ndarray, shape (M, K)
    rcond : float
        A problem whose scaled triangular factor has ``min|diag| / max|diag| < rcond``
        is treated as rank-deficient.
    without_q : bool
        Factor ``[A D^-1, y]`` and read ``Q'y`` from its last column instead of forming Q:
        2-4x faster on the sweep's stacks of candidates (N = 2000, 60 columns). Stage 2's
        single tall problem keeps forming Q: there the factor without Q runs OpenBLAS's
        threaded path, whose threads then compete with the compiled sums (Pitot warm
        estimate 0.50-0.56 s -> 0.61-0.67 s).

    Returns
    -------
    x : ndarray, shape (M, n)
        Solutions; NaN rows for rank-deficient problems.
    full_rank : ndarray of bool, shape (M,)
    """
    M, K, n = A.shape
    finite = np.isfinite(A).all(axis=(1, 2)) & np.isfinite(y).all(axis=1)
    if n == 0:
        return np.zeros((M, 0)), finite
    if K < n:  # fewer equations than unknowns
        return np.full((M, n), np.nan), np.zeros(M, dtype=bool)
    if not finite.all():  # a model that is NaN or infinite somewhere: no fit there
        A, y = np.where(finite[:, None, None], A, 0.0), np.where(finite[:, None], y, 0.0)
    norms = np.linalg.norm(A, axis=1)  # (M, n)
    safe = np.where(norms > 0, norms, 1.0)
    if without_q:  # the triangular factor of [A D^-1, y]: its first n columns are R, its last Q'y
        augmented = np.linalg.qr(np.concatenate([A / safe[:, None, :], y[:, :, None]], axis=2), mode="r")
        Rf, qty = augmented[:, :n, :n], augmented[:, :n, n]
    else:
        Q, Rf = np.linalg.qr(A / safe[:, None, :])
        qty = np.einsum("mkn,mk->mn", Q, y)
    diag = np.abs(np.diagonal(Rf, axis1=1, axis2=2))
    full_rank = finite & (norms > 0).all(axis=1) & (diag.min(axis=1) > rcond * diag.max(axis=1))
    x = np.full((M, n), np.nan)
    if full_rank.any():
        sol = np.linalg.solve(Rf[full_rank], qty[full_rank][..., None])[..., 0]
        x[full_rank] = sol / safe[full_rank]
    return x, full_rank


def condition_below(P: np.ndarray, limit: float) -> np.ndarray:
    """Whether each symmetric positive semi-definite matrix has ``lambda_min * limit > lambda_max``,
    decided as by ``numpy.linalg.eigvalsh``, for a stack of small matrices.

    A Cholesky factor ``P = L L'`` computed in NumPy across the stack (loops over the n columns,
    not over the M matrices) bounds the ratio: ``lambda_max <= trace P`` and ``lambda_min >=
    1 / ||L^-1||_F^2``. A matrix whose bound is ``SCREEN_MARGIN`` times below the limit is
    decided by it (eigvalsh's own rounding there is ~n eps cond, far from the limit); the others,
    and any whose factor breaks down, by eigvalsh, so the answer equals eigvalsh's test while
    LAPACK runs only on the few matrices near the limit (its per-matrix call dominates on the sweep's
    small matrices).

    Parameters
    ----------
    P : ndarray, shape (M, n, n)
        Symmetric, finite (the sweep's column-scaled normal matrices).
    limit : float
        Largest accepted ratio of the extreme eigenvalues.

    Returns
    -------
    ndarray of bool, shape (M,)
    """
    M, n = P.shape[0], P.shape[1]
    sure = np.zeros(M, dtype=bool)
    if M and n and limit <= SCREENED_LIMIT:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # a breakdown only sends it to eigvalsh
            sure = _cholesky_bound(P) * SCREEN_MARGIN < limit
    below_limit = sure.copy()
    rest = ~sure
    if rest.any():
        eig = np.linalg.eigvalsh(P[rest])
        below_limit[rest] = eig[:, 0] * limit > eig[:, -1]
    return below_limit


def _cholesky_bound(P: np.ndarray) -> np.ndarray:
    """``trace P * ||L^-1||_F^2`` for each ``P = L L'`` of the stack, an upper bound of its condition
    number; NaN where the factor breaks down (a pivot not above zero), shape (M,)."""
    M, n = P.shape[0], P.shape[1]
    L = np.zeros_like(P)
    factored = np.ones(M, dtype=bool)
    for j in range(n):
        pivot = P[:, j, j] - np.einsum("mk,mk->m", L[:, j, :j], L[:, j, :j])
        factored &= pivot > 0
        L[:, j, j] = np.sqrt(np.where(pivot > 0, pivot, 1.0))
        below = P[:, j + 1:, j] - np.einsum("mik,mk->mi", L[:, j + 1:, :j], L[:, j, :j])
        L[:, j + 1:, j] = below / L[:, j, j][:, None]
    inverse = np.zeros_like(P)  # L^-1 by forward substitution, row by row
    for i in range(n):
        inverse[:, i, i] = 1.0 / L[:, i, i]
        if i:
            inverse[:, i, :i] = -np.einsum("mk,mkj->mj", L[:, i, :i], inverse[:, :i, :i]) / L[:, i, i][:, None]
    bound = np.trace(P, axis1=1, axis2=2) * np.einsum("mij,mij->m", inverse, inverse)
    return np.where(factored & np.isfinite(bound), bound, np.nan)


def refined_least_squares(A: np.ndarray, y: np.ndarray, normal: np.ndarray, scales: np.ndarray,
                          max_condition: float = 1e15, rtol: float = 1e-12, max_iter: int = 60
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``min ||A_m x - y_m||`` by conjugate gradients on A itself, preconditioned by the
    normal matrices of the Gram sums.

    The normal matrix P (rounded in forming the Gram sums) is an accurate preconditioner of
    the exact ``A'A``: the preconditioned spectrum lies within about cond(P) eps of 1, so
    conjugate gradients on ``A'A x = A'y`` (products with A and A' only, 4 K n flops a pass,
    against the 2 K n^2 of a QR) converge in a few passes even where cond(P) eps approaches
    0.1, where the plain iterative refinement ``P dx = A' r`` contracts only by that factor a
    pass. The preconditioner is applied through P's eigendecomposition. A problem is solved
    when its residual sum of squares, updated each pass, changes by less than ``rtol``
    (relative) between passes (callers compute the final residuals from A themselves).

    Parameters
    ----------
    A : ndarray, shape (M, K, n)
    y : ndarray, shape (M, K)
    normal : ndarray, shape (M, n, n)
        Column-scaled normal matrices ``D^-1 A'A D^-1`` (from the Gram sums).
    scales : ndarray, shape (M, n)
        The column norms D.
    max_condition : float
        Problems whose ``normal`` is worse conditioned are left unsolved (for QR to decide).
    rtol : float
    max_iter : int

    Returns
    -------
    x : ndarray, shape (M, n)
        Solutions (NaN where not solved).
    solved : ndarray of bool, shape (M,)
    """
    M, K, n = A.shape
    eig, vec = np.linalg.eigh(np.where(np.isfinite(normal), normal, 0.0))
    solved = (np.isfinite(A).all(axis=(1, 2)) & np.isfinite(y).all(axis=1) & (scales > 0).all(axis=1)
              & (eig[:, 0] * max_condition > eig[:, -1]) & (eig[:, 0] > 0))
    x = np.full((M, n), np.nan)
    if not solved.any():
        return x, solved
    As = A[solved] / scales[solved][:, None, :]
    AsT = np.ascontiguousarray(As.transpose(0, 2, 1))
    V, inv_eig, ys = vec[solved], 1.0 / eig[solved], y[solved]

    def precondition(r):  # P^-1 r through P = V diag(eig) V'
        return np.einsum("mij,mj->mi", V, inv_eig * np.einsum("mji,mj->mi", V, r))

    xs = precondition(np.einsum("mnk,mk->mn", AsT, ys))
    error = ys - np.einsum("mkn,mn->mk", As, xs)  # y - A x
    grad = np.einsum("mnk,mk->mn", AsT, error)
    z = precondition(grad)
    direction, rz = z.copy(), np.einsum("mn,mn->m", grad, z)
    previous, settled = np.sum(error**2, axis=1), np.zeros(len(As), dtype=bool)
    for _ in range(max_iter):
        Ap = np.einsum("mkn,mn->mk", As, direction)
        curvature = np.einsum("mk,mk->m", Ap, Ap)
        step = np.where(settled | (curvature <= 0), 0.0, rz / np.where(curvature > 0, curvature, 1.0))
        xs += step[:, None] * direction
        error -= step[:, None] * Ap
        grad -= step[:, None] * np.einsum("mnk,mk->mn", AsT, Ap)
        rss = np.sum(error**2, axis=1)
        settled |= np.abs(previous - rss) <= rtol * np.maximum(rss, 1e-300)
        previous = rss
        if settled.all():
            break
        z = precondition(grad)
        rz_new = np.einsum("mn,mn->m", grad, z)
        direction = z + (rz_new / np.where(rz != 0, rz, 1.0))[:, None] * direction
        rz = rz_new
    x[solved] = np.where(settled[:, None], xs / scales[solved], np.nan)
    solved[np.flatnonzero(solved)[~settled]] = False
    return x, solved


def box_least_squares(P: np.ndarray, q: np.ndarray, lb: np.ndarray, ub: np.ndarray, max_iter: int = 50) -> np.ndarray:
    """Solve ``min x'Px - 2 q'x`` subject to ``lb <= x <= ub`` for a stack of problems.

    The bounded linear least squares ``min ||A x - y||`` with ``P = A'A``, ``q = A'y``,
    exact for the small numbers of linear parameters of calibration models. Primal-dual
    active-set iteration (Hintermueller, Ito and Kunisch 2002) on the column-scaled
    problem, all problems at once; the few that do not settle in ``max_iter`` passes are
    solved one by one by SciPy's bounded-variable least squares on the Cholesky factor.

    Parameters
    ----------
    P : ndarray, shape (M, n, n)
        Symmetric positive definite Gram matrices.
    q : ndarray, shape (M, n)
    lb, ub : ndarray, shape (n,)
        Bounds (``-inf``/``inf`` for none).
    max_iter : int

    Returns
    -------
    x : ndarray, shape (M, n)
    """
    M, n = q.shape
    d = np.sqrt(np.maximum(np.diagonal(P, axis1=1, axis2=2), 1e-300))
    Ps = P / (d[:, :, None] * d[:, None, :])
    qs = q / d
    lo, hi = lb[None, :] * d, ub[None, :] * d
    y = solve_stack(Ps, qs)  # the unconstrained solutions
    mu = np.zeros((M, n))  # multipliers: qs - Ps y on the active set, 0 on the free set
    lower = np.zeros((M, n), dtype=bool)
    upper = np.zeros((M, n), dtype=bool)
    todo = np.ones(M, dtype=bool)
    eye = np.eye(n)
    for _ in range(max_iter):
        new_lower = (y + mu < lo) & todo[:, None]
        new_upper = (y + mu > hi) & todo[:, None] & ~new_lower
        settled = todo & np.all(new_lower == lower, axis=1) & np.all(new_upper == upper, axis=1)
        todo &= ~settled
        if not todo.any():
            break
        lower[todo], upper[todo] = new_lower[todo], new_upper[todo]
        active = (lower | upper)[todo]
        K = np.where(active[:, :, None], eye[None], Ps[todo])
        rhs = np.where(lower[todo], lo[todo], np.where(upper[todo], hi[todo], qs[todo]))
        y[todo] = solve_stack(K, rhs)
        grad = qs[todo] - np.einsum("mij,mj->mi", Ps[todo], y[todo])
        mu[todo] = np.where(active, grad, 0.0)
    x = y / d
    if todo.any():
        from scipy.optimize import lsq_linear

        for m in np.flatnonzero(todo):
            factor = gram_factor(P[m])
            target = np.linalg.lstsq(factor.T, q[m], rcond=None)[0]
            x[m] = lsq_linear(factor, target, bounds=(lb, ub), method="bvls", tol=1e-14).x
    return np.clip(x, lb, ub)


def solve_stack(K: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``K_m x_m = rhs_m`` for a stack of square systems: one batched solve, or where a system is
    singular (a candidate whose columns coincide, or vanish at the data: equal rates of a sum of
    exponentials, a rate at zero where the data start at x = 0) each system alone, the singular
    ones by their least-norm least-squares solution.

    Parameters
    ----------
    K : ndarray, shape (M, n, n)
    rhs : ndarray, shape (M, n)

    Returns
    -------
    ndarray, shape (M, n)
    """
    try:
        return np.linalg.solve(K, rhs[..., None])[..., 0]
    except np.linalg.LinAlgError:
        out = np.empty(rhs.shape)
        for m in range(K.shape[0]):
            try:
                out[m] = np.linalg.solve(K[m], rhs[m])
            except np.linalg.LinAlgError:
                out[m] = np.linalg.lstsq(K[m], rhs[m], rcond=None)[0]
        return out


def gram_factor(P: np.ndarray) -> np.ndarray:
    """A square factor F with ``F' F = P`` of a symmetric positive semi-definite Gram matrix: its
    Cholesky factor, or where P is singular ``sqrt(w) U'`` of its eigen-decomposition.

    Parameters
    ----------
    P : ndarray, shape (n, n)

    Returns
    -------
    ndarray, shape (n, n)
    """
    try:
        return np.linalg.cholesky(P).T
    except np.linalg.LinAlgError:
        w, U = np.linalg.eigh(0.5 * (P + P.T))
        return np.sqrt(np.maximum(w, 0.0))[:, None] * U.T


def feasible_solutions(AtA, Aty, yty, x, rss, ok, lb, ub):
    """Replace the xi1 (and per-channel RSS) that leave the box by the best feasible ones."""
    if lb is None or x.shape[1] == 0:
        return x, rss
    outside = ok & np.any((x < lb) | (x > ub), axis=1)
    if not outside.any():
        return x, rss
    x, rss = x.copy(), rss.copy()
    P, q = AtA[outside].sum(axis=1), Aty[outside].sum(axis=1)
    xb = box_least_squares(P, q, lb, ub)
    x[outside] = xb
    sub_AtA, sub_Aty = AtA[outside], Aty[outside]
    rss[outside] = np.maximum(
        yty[outside] - 2 * np.einsum("mjn,mn->mj", sub_Aty, xb) + np.einsum("mn,mjnk,mk->mj", xb, sub_AtA, xb), 0.0
    )
    return x, rss
