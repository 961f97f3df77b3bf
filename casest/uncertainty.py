"""Covariance and standard deviations of the estimate.

Default (``method="hessian"``, the paper's choice): the inverse of the exact Hessian of
J(theta, rho) (Eq. 6, rho = ln R) at the optimum; the theta block of that inverse is the
covariance. This equals the inverse Hessian of the profile cost min_R J, so it accounts
for R being estimated. ``"hessian-dof"`` multiplies by N m / (N m - p) to undo the low
bias of the ML noise variance. ``"gauss-newton"`` is (sum_k J_k' R^-1 J_k)^-1 and
``"gauss-newton-dof"`` adds the same factor (NIST's convention, s^2 = RSS / (n - p)).

Parameters on an active bound are held fixed: their std is unavailable (``None``), with
the reason, and the others' covariance is conditional on them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .data import Dataset
from .model import Model, OptionError
from .noise import CorrelatedNoise, KnownNoise
from .problem import Problem, as_problem
from .ipopt import SolverSettings
from .status import Note, NoteCode, StdReason

__all__ = [
    "COVARIANCE_METHODS",
    "Uncertainty",
    "covariance_from_hessian",
    "std_from_covariance",
    "correlation",
    "parameter_uncertainty",
]

COVARIANCE_METHODS = ("hessian", "hessian-dof", "gauss-newton", "gauss-newton-dof")


def covariance_from_hessian(H: np.ndarray, rcond: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of a symmetric positive definite Hessian, with its null directions.

    Formula: ``C = H^-1``, computed on ``D H D`` with ``D = diag(H)^-1/2`` so that the
    test for singularity does not depend on the parameters' units.

    Parameters
    ----------
    H : ndarray, shape (n, n)
    rcond : float
        Eigenvalues of the scaled matrix below ``rcond * max eigenvalue`` count as zero.

    Returns
    -------
    C : ndarray, shape (n, n)
        The inverse; NaN everywhere if ``H`` is singular or indefinite.
    null : ndarray, shape (n, k)
        Unit directions (scaled coordinates) along which ``H`` is singular or negative;
        empty (k = 0) when ``H`` is positive definite.

    Notes
    -----
    A clearly negative eigenvalue means the point is not a minimum (for example an
    unconverged solve); :func:`is_indefinite` tells the two failure modes apart.
    """
    H = 0.5 * (H + H.T)
    n = H.shape[0]
    if n == 0:
        return np.zeros((0, 0)), np.zeros((0, 0))
    d = np.sqrt(np.abs(np.diag(H)))
    d = np.where(d > 0, d, 1.0)
    Hs = H / np.outer(d, d)
    w, V = np.linalg.eigh(Hs)
    bad = w <= rcond * max(w[-1], 0.0)
    if np.any(bad) or w[-1] <= 0:
        return np.full((n, n), np.nan), V[:, bad]
    Cs = (V / w) @ V.T
    return Cs / np.outer(d, d), np.zeros((n, 0))


def is_indefinite(H: np.ndarray, rcond: float = 1e-12) -> bool:
    """True when the unit-scaled ``H`` has an eigenvalue below ``-rcond * max eigenvalue``."""
    if H.size == 0:
        return False
    d = np.sqrt(np.abs(np.diag(H)))
    d = np.where(d > 0, d, 1.0)
    w = np.linalg.eigvalsh(0.5 * (H + H.T) / np.outer(d, d))
    return bool(w[0] < -rcond * max(abs(w[-1]), 1.0))


def std_from_covariance(C: np.ndarray) -> np.ndarray:
    """Standard deviations ``sqrt(diag(C))``, shape (n,); NaN where the diagonal is not positive."""
    diag = np.diag(C).copy()
    with np.errstate(invalid="ignore"):
        return np.where(diag > 0, np.sqrt(np.where(diag > 0, diag, 0.0)), np.nan)


def correlation(C: np.ndarray) -> np.ndarray:
    """Correlation ``C_ij / (s_i s_j)``, shape (n, n); NaN rows for unavailable std."""
    s = std_from_covariance(C)
    with np.errstate(invalid="ignore", divide="ignore"):
        K = C / np.outer(s, s)
    np.fill_diagonal(K, np.where(np.isfinite(s), 1.0, np.nan))
    return K


@dataclass
class Uncertainty:
    """Covariance of the parameters and why some std are missing.

    Attributes
    ----------
    covariance : ndarray, shape (n_parameters, n_parameters)
        NaN in the rows/columns of parameters without std.
    std : ndarray, shape (n_parameters,)
        NaN where unavailable.
    reasons : list of (str or None)
        Why each std is unavailable (``None`` where it is available).
    method : str
    notes : list of str
        How the noise level was obtained where it was not the ML estimate (exact fits).
    reason_codes : list of (StdReason or None)
        The code of each reason.
    """

    covariance: np.ndarray
    std: np.ndarray
    reasons: list
    method: str
    notes: list = field(default_factory=list)
    reason_codes: list = field(default_factory=list)


def parameter_uncertainty(
    model: Model | Problem,
    data: Dataset | None,
    theta: np.ndarray,
    R: np.ndarray,
    active: list | None = None,
    r_at_floor: np.ndarray | None = None,
    method: str = "hessian",
    r_known: bool = False,
    prior_precision: np.ndarray | None = None,
    R_full: np.ndarray | None = None,
) -> Uncertainty:
    """Covariance of theta at the estimate.

    Parameters
    ----------
    model, data : Model and Dataset, or Problem and None
        A :class:`casest.Problem` brings its noise model (``r_known``, ``R_full``) and its
        prior penalties (``prior_precision``); leave those options out then.
    theta : ndarray, shape (n_parameters,)
        The estimate (of the problem's model: fixed parameters are not in it).
    R : ndarray, shape (n_outputs,), or (n_outputs, n_outputs) for a full R
    active : list of (str or None), length n_parameters, optional
        ``"lower"``/``"upper"`` for parameters on an active bound (default: none).
    r_at_floor : ndarray of bool, shape (n_outputs,), optional
        Noise variances held at the floor (their rho is treated as fixed).
    method : one of :data:`COVARIANCE_METHODS`
    r_known : bool
        R is known (given, not estimated): its rows are held fixed and the std follow
        from the given R.
    R_full : ndarray, shape (n_outputs, n_outputs), optional
        A full estimated noise covariance: the Hessian is taken in (theta, log-Cholesky
        of R), so the std account for the correlated R being estimated.
    prior_precision : ndarray, shape (n_parameters,), optional
        1/std^2 of Gaussian priors that entered the cost as penalties (MAP): added to the
        Hessian (or Gauss-Newton matrix), so the covariance is the posterior one.

    Returns
    -------
    Uncertainty
    """
    if method not in COVARIANCE_METHODS:
        raise OptionError(f"covariance method must be one of {COVARIANCE_METHODS}, got {method!r}")
    R = np.asarray(R, dtype=float)
    if isinstance(model, Problem):
        if r_known or prior_precision is not None or R_full is not None:
            raise OptionError("with a casest.Problem the noise model and priors come from the Problem")
        problem = as_problem(model, data)
        r_known = not problem.noise.estimated
        prior_precision = None if problem.penalty is None else problem.penalty.precision
        if problem.full_noise:
            R_full = R if R.ndim == 2 else None
            if R_full is None:
                raise OptionError("a Problem with CorrelatedNoise needs the full R (n_outputs x n_outputs)")
    else:
        noise = (CorrelatedNoise() if R_full is not None else
                 KnownNoise(dict(zip(model.output_names, np.sqrt(R.reshape(-1)).tolist()))) if r_known else None)
        problem = Problem(model, data, noise=noise)
    if R.ndim == 2:
        R = np.diag(R).copy()
    model, data = problem.model, problem.data
    theta = problem.vector(theta)
    active = [None] * model.n_parameters if active is None else active
    n, ny = model.n_parameters, model.n_outputs
    names = model.parameter_names
    reasons: list = [None] * n
    codes: list = [None] * n
    for i, side in enumerate(active):
        if side:
            reasons[i] = f"at {side} bound: held fixed, std not available"
            codes[i] = StdReason.ACTIVE_BOUND
    free = [i for i in range(n) if reasons[i] is None]
    floor_mask = np.zeros(ny, dtype=bool) if r_at_floor is None else np.asarray(r_at_floor, dtype=bool)
    notes = []
    R = np.asarray(R, dtype=float).copy()
    if r_known:
        floor_mask = np.ones(ny, dtype=bool)  # every rho held at the given R
    elif floor_mask.any():
        # an exact fit: R at the noise floor says nothing about the noise. Use the residual
        # mean square with the degrees-of-freedom correction, RSS_j / (N - n / n_y), as NIST does
        resid = np.nan_to_num(problem.residuals(theta))  # 0 where not measured
        rss = np.sum(resid**2, axis=0)
        counts = data.observed_counts()
        # the "-dof" methods apply N m / (N m - n) to the whole covariance below
        dof = counts if method.endswith("-dof") else counts - n / ny
        dof = np.where(floor_mask, dof, 1.0)
        zero = floor_mask & (rss <= 0.0)
        if zero.any() or np.any(dof <= 0):
            for i in free:
                codes[i] = StdReason.NO_NOISE_ESTIMATE
                reasons[i] = ("exact fit with zero residual (or no degrees of freedom): the noise level, and so "
                              "the std, cannot be estimated")
            free = []
        else:
            R[floor_mask] = rss[floor_mask] / dof[floor_mask]
            channels = [c for c, f in zip(model.output_names, floor_mask) if f]
            notes.append(Note(
                f"the data of {channels} are fitted exactly (R at the noise floor): their noise variance for the "
                f"std is RSS / (N - n/m) = {', '.join(f'{r:.3g}' for r in R[floor_mask])} (NIST's convention), "
                "not the floor", NoteCode.STD_FROM_RSS))

    if method.startswith("hessian"):
        settings = SolverSettings()
        N = problem.n_samples
        noise_vector = problem.noise_vector(R_full if R_full is not None else R)
        hessian = problem.cost_hessian(settings.resolved_threads(N), settings.resolved_jit(N), settings.jit_flags)
        with problem.data_argument() as data_arg:
            _, H = hessian(theta, noise_vector, data_arg)
        H = np.asarray(H)
        # the noise rows: all of a full R's log-Cholesky vector, the ln R_j not held at the floor
        keep = free + [n + j for j in range(len(noise_vector)) if R_full is not None or not floor_mask[j]]
    elif R_full is not None:
        Jb = problem.jacobian(theta).reshape(data.n_samples, ny, n)  # blocks of n_y rows per sample
        W = np.linalg.inv(np.asarray(R_full, dtype=float))
        H = np.einsum("kia,ij,kjb->ab", Jb, W, Jb)
        keep = free
    else:
        Jr = problem.jacobian(theta)  # rows of outputs not measured are zero
        w = np.tile(1.0 / R, data.n_samples)
        H = (Jr * w[:, None]).T @ Jr
        keep = free
    if prior_precision is not None:
        H = H.copy()
        H[np.arange(n), np.arange(n)] += np.asarray(prior_precision, dtype=float)
    C_keep, null = covariance_from_hessian(H[np.ix_(keep, keep)])
    cov = np.full((n, n), np.nan)
    if null.shape[1] and is_indefinite(H[np.ix_(keep, keep)]):
        for i in free:
            reasons[i] = "the Hessian is not positive definite here (not a minimum): std not available"
            codes[i] = StdReason.NOT_A_MINIMUM
        free, C_keep = [], np.zeros((len(keep), len(keep)))
    elif null.shape[1]:
        # name the parameters in the singular directions; the rest stays conditional on them
        involved = sorted({keep[i] for i in np.flatnonzero(np.max(np.abs(null), axis=1) > 0.2) if keep[i] < n})
        if not involved:
            involved = free
        for i in involved:
            codes[i] = StdReason.NOT_IDENTIFIABLE
            reasons[i] = (
                "not identifiable from these data: the cost is flat (singular Hessian) along a "
                f"direction involving {[names[j] for j in involved]}"
            )
        free = [i for i in free if i not in involved]
        keep = free + [k for k in keep if k >= n]
        C_keep, null = covariance_from_hessian(H[np.ix_(keep, keep)])
        if null.shape[1]:
            for i in free:
                reasons[i] = "Hessian singular at the estimate: std not available"
                codes[i] = StdReason.SINGULAR
            free, C_keep = [], np.zeros((len(keep), len(keep)))
    nf = len(free)
    cov[np.ix_(free, free)] = C_keep[:nf, :nf]
    if method.endswith("-dof"):
        m = int(data.observed_counts().sum())
        if m <= n:
            raise OptionError("degrees-of-freedom correction needs more measurements than parameters")
        cov *= m / (m - n)
    return Uncertainty(covariance=cov, std=std_from_covariance(cov), reasons=reasons, method=method, notes=notes,
                       reason_codes=codes)
