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

import casadi as ca
import numpy as np

from .data import Dataset
from .model import Model, OptionError
from .status import Note, NoteCode, StdReason
from .sums import residual_jacobian

__all__ = [
    "COVARIANCE_METHODS",
    "Uncertainty",
    "covariance_from_hessian",
    "std_from_covariance",
    "correlation",
    "parameter_uncertainty",
    "cost_hessian",
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


def cost_hessian(model: Model, n_samples: int, masked: bool = False, full_noise: bool = False) -> ca.Function:
    """``(theta, rho, data) -> (J, H)``: Eq. 6 and its exact Hessian in (theta, rho = ln R).

    ``full_noise``: rho is the log-Cholesky vector of a full R (see :func:`casest.sums.cholesky_factor`).

    The data vector is :func:`casest.stage2.data_vector`; theta is physical. Built from
    the per-sample exact Hessians of :mod:`casest.sums` (cached per model and N).
    """
    from .stage2 import SolverSettings, data_symbols
    from .sums import ml_sums, symmetric

    settings = SolverSettings()
    sums = ml_sums(model, n_samples, np.ones(model.n_parameters), settings.resolved_threads(n_samples),
                   settings.resolved_jit(n_samples), settings.jit_flags, masked, full_noise)
    p, X, Z = data_symbols(model, n_samples, masked)
    theta = ca.MX.sym("theta", model.n_parameters)
    from .sums import n_cholesky

    # the noise block: ln R_j, or the log-Cholesky vector of a full R
    rho = ca.MX.sym("rho", n_cholesky(model.n_outputs) if full_noise else model.n_outputs)
    w = ca.vertcat(theta, rho)
    J = sums.cost(w, X, Z) * n_samples
    H = symmetric(sums.hessian(w, X, Z)) * n_samples
    return ca.Function("J_hess", [theta, rho, p], [J, H], ["theta", "rho", "data"], ["J", "H"])


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
    model: Model,
    data: Dataset,
    theta: np.ndarray,
    R: np.ndarray,
    active: list,
    r_at_floor: np.ndarray | None = None,
    method: str = "hessian",
    r_known: bool = False,
    prior_precision: np.ndarray | None = None,
    R_full: np.ndarray | None = None,
) -> Uncertainty:
    """Covariance of theta at the estimate.

    Parameters
    ----------
    model, data : Model, Dataset
    theta : ndarray, shape (n_parameters,)
    R : ndarray, shape (n_outputs,)
    active : list of (str or None), length n_parameters
        ``"lower"``/``"upper"`` for parameters on an active bound.
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
        resid = np.nan_to_num(data.outputs - model.predict(theta, data.signals))  # 0 where not measured
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

    if method.startswith("hessian") and R_full is not None:
        from .stage2 import cholesky_vector, data_vector

        ell = cholesky_vector(np.asarray(R_full, dtype=float))
        _, H = cost_hessian(model, data.n_samples, full_noise=True)(theta, ell, data_vector(data))
        H = np.asarray(H)
        keep = free + [n + j for j in range(len(ell))]
    elif method.startswith("hessian"):
        from .stage2 import data_vector

        _, H = cost_hessian(model, data.n_samples, data.has_missing)(theta, np.log(R), data_vector(data))
        H = np.asarray(H)
        keep = free + [n + j for j in range(ny) if not floor_mask[j]]
    elif R_full is not None:
        Jr = residual_jacobian(model, data, theta)  # sample-major rows: blocks of n_y per sample
        W = np.linalg.inv(np.asarray(R_full, dtype=float))
        Jb = Jr.reshape(data.n_samples, ny, n)
        H = np.einsum("kia,ij,kjb->ab", Jb, W, Jb)
        keep = free
    else:
        Jr = residual_jacobian(model, data, theta)
        w = (data.output_mask() / np.asarray(R, dtype=float)).reshape(-1)  # a missing output weighs 0
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
