"""Covariance and standard deviations of the estimate.

Default (``method="hessian"``, the paper's choice): the inverse of the exact Hessian of
J(theta, rho) (Eq. 6, rho = ln R) at the optimum; the theta block of that inverse is the
covariance. This equals the inverse Hessian of the profile cost min_R J, so it accounts
for R being estimated. ``"gauss-newton"`` is (sum_k J_k' R^-1 J_k)^-1. Either takes the
degrees-of-freedom correction (``dof_correction=True``): the covariance times N m / (N m - p),
undoing the low bias of the ML noise variance (NIST's convention, s^2 = RSS / (n - p)).

Parameters on an active bound are held fixed: their std is unavailable (``None``), with
the reason, and the others' covariance is conditional on them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..checks import noise_variances, flag_argument
from ..options import CovarianceMethod, check_option, choices
from ..backend.ipopt import SolverSettings
from ..backend.noise_terms import DIAGONAL
from ..data.dataset import Dataset
from ..models import Model, OptionError
from ..problem.problem import Problem, as_problem
from ..status import Note, NoteCode, StdReason


__all__ = [
    "std_from_covariance",
    "std_from_information",
    "COVARIANCE_METHODS",
    "Uncertainty",
    "covariance_from_hessian",
    "std_from_covariance",
    "correlation",
    "parameter_uncertainty",
]

COVARIANCE_METHODS = choices(CovarianceMethod)


def std_from_information(information: np.ndarray) -> np.ndarray:
    """Standard deviations from an information matrix: all NaN where it is singular or
    indefinite (:func:`covariance_from_hessian`), as a batch estimate reports them.

    Parameters
    ----------
    information : ndarray, shape (n, n)

    Returns
    -------
    ndarray, shape (n,)
    """
    covariance, _ = covariance_from_hessian(np.asarray(information, dtype=float))
    return std_from_covariance(covariance)


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
    """Standard deviations ``sqrt(diag(C))``.

    Parameters
    ----------
    C : ndarray, shape (n, n)
        A covariance matrix.

    Returns
    -------
    ndarray, shape (n,)
        Standard deviations (units of the parameters); NaN where the diagonal is not positive.
    """
    diag = np.diag(C).copy()
    with np.errstate(invalid="ignore"):
        return np.where(diag > 0, np.sqrt(np.where(diag > 0, diag, 0.0)), np.nan)


def correlation(C: np.ndarray) -> np.ndarray:
    """Correlation matrix of a covariance, ``C_ij / (s_i s_j)``.

    Parameters
    ----------
    C : ndarray, shape (n, n)
        A covariance matrix (units of the parameters, products).

    Returns
    -------
    ndarray, shape (n, n)
        Correlations (dimensionless); NaN in the rows and columns whose std is unavailable.
    """
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
    method : {"hessian", "gauss-newton"}
        The information matrix inverted.
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
    dof_correction: bool = False


def parameter_uncertainty(
    model: Model | Problem,
    data: Dataset | None,
    theta: np.ndarray,
    R: np.ndarray,
    active: list | None = None,
    r_at_floor: np.ndarray | None = None,
    method: CovarianceMethod = "hessian",
    settings: SolverSettings | None = None,
    dof_correction: bool = False,
) -> Uncertainty:
    """Covariance of theta at the estimate.

    Parameters
    ----------
    model, data : Model and Dataset, or Problem and None
        A :class:`casest.Problem` brings its noise model (known, diagonal or full R) and its
        prior penalties; a Model and data are the problem with R unknown and diagonal.
    theta : ndarray, shape (n_parameters,)
        The estimate (of the problem's model: fixed parameters are not in it).
    R : ndarray, shape (n_outputs,), or (n_outputs, n_outputs) for a full R
    active : list of (str or None), length n_parameters, optional
        ``"lower"``/``"upper"`` for parameters on an active bound (default: none).
    r_at_floor : ndarray of bool, shape (n_outputs,), optional
        Noise variances held at the floor (their rho is treated as fixed).
    method : one of :data:`COVARIANCE_METHODS`
    settings : SolverSettings, optional
        The estimate's settings: the exact Hessian's sums compile and thread as the solve's did
        (default casest's).
    dof_correction : bool
        Multiply the covariance by N m / (N m - p) (m measurements per sample, p parameters).

    Returns
    -------
    Uncertainty
    """
    check_option("covariance method", method, CovarianceMethod)
    dof_correction = flag_argument(dof_correction, "dof_correction")
    problem, R_given, precision = _problem_at_estimate(model, data, R)
    R_given = problem.noise.std_covariance(R_given)  # variances, or a full noise model's full R
    variances = noise_variances(np.diag(R_given) if R_given.ndim == 2 else R_given, problem.model.output_names)
    theta = problem.vector(theta)
    n = problem.model.n_parameters
    reasons = _Reasons(n)
    for i, side in enumerate([None] * n if active is None else active):
        if side:
            reasons.hold([i], StdReason.ACTIVE_BOUND, f"at {side} bound: held fixed, std not available")
    at_floor = problem.noise.floor_channels(r_at_floor, problem.model.n_outputs)
    R, notes = _noise_for_std(problem, variances, theta, at_floor, dof_correction, reasons)
    held = problem.noise.held_rows(at_floor)
    _hold_unidentified(problem, theta, R, reasons)
    # a full R enters as it is (no channel is held at a floor); diagonal R: the variances for the std
    H, keep = _information(problem, theta, R_given if R_given.ndim == 2 else R, held, method, reasons.free,
                           settings or SolverSettings())
    if precision is not None:
        H = H.copy()
        H[np.arange(n), np.arange(n)] += np.asarray(precision, dtype=float)
    cov = _covariance(H, keep, reasons, problem.model.parameter_names)
    if dof_correction:
        m = int(problem.data.observed_counts().sum())
        if m <= n:
            raise OptionError("degrees-of-freedom correction needs more measurements than parameters")
        cov *= m / (m - n)
    return Uncertainty(covariance=cov, std=std_from_covariance(cov), reasons=reasons.reasons, method=method,
                       notes=notes, reason_codes=reasons.codes, dof_correction=bool(dof_correction))


class _Reasons:
    """Why each parameter has no std (None where it has one), with its code."""

    def __init__(self, n: int):
        self.reasons: list = [None] * n
        self.codes: list = [None] * n

    @property
    def free(self) -> list:
        """The parameters that still get a std."""
        return [i for i, r in enumerate(self.reasons) if r is None]

    def hold(self, indices, code: StdReason, text: str) -> None:
        for i in indices:
            self.reasons[i], self.codes[i] = text, code


def _problem_at_estimate(model, data, R) -> tuple:
    """The Problem whose noise model the std use, the R given (variances, or a full R), and the
    precisions of the prior penalties (None without priors). A Problem brings its own; a Model
    and data are the problem with R unknown and diagonal."""
    problem = as_problem(model, data) if isinstance(model, Problem) else Problem(model, data)
    return problem, np.asarray(R, dtype=float), None if problem.penalty is None else problem.penalty.precision


def _noise_for_std(problem: Problem, variances: np.ndarray, theta, held: np.ndarray, dof_correction: bool,
                   reasons: _Reasons) -> tuple:
    """The R the std use, and its notes: an R at the noise floor (``held``: an exact fit says
    nothing about the noise) becomes the residual mean square with the degrees-of-freedom
    correction, RSS_j / (N - n / n_y), as NIST does."""
    R = variances.copy()
    n, ny = problem.model.n_parameters, problem.model.n_outputs
    if not held.any():
        return R, []
    rss = np.sum(np.nan_to_num(problem.residuals(theta)) ** 2, axis=0)  # 0 where not measured
    counts = problem.data.observed_counts()
    # the degrees-of-freedom correction applies N m / (N m - n) to the whole covariance instead
    dof = np.where(held, counts if dof_correction else counts - n / ny, 1.0)
    if np.any(held & (rss <= 0.0)) or np.any(dof <= 0):
        reasons.hold(reasons.free, StdReason.NO_NOISE_ESTIMATE, "exact fit with zero residual (or no degrees of "
                     "freedom): the noise level, and so the std, cannot be estimated")
        return R, []
    R[held] = rss[held] / dof[held]
    channels = [c for c, f in zip(problem.model.output_names, held) if f]
    return R, [Note(
        f"the data of {channels} are fitted exactly (R at the noise floor): their noise variance for the "
        f"std is RSS / (N - n/m) = {', '.join(f'{r:.3g}' for r in R[held])} (NIST's convention), "
        "not the floor", NoteCode.STD_FROM_RSS)]


def _information(problem: Problem, theta, R, held, method: str, free: list, settings: SolverSettings) -> tuple:
    """The matrix whose inverse is the covariance (the exact Hessian of J, or the Gauss-Newton
    information), and the rows kept: the free parameters and the noise rows not held."""
    n, N = problem.model.n_parameters, problem.n_samples
    if method == "hessian":
        noise_vector = problem.noise_vector(R)
        hessian = problem.cost_hessian(settings.resolved_threads(N), settings.resolved_jit(N), settings.jit_flags)
        with problem.data_argument() as data_arg:
            _, H = hessian(theta, noise_vector, data_arg)
        # the noise rows not held at the floor (a full R's log-Cholesky vector has none held)
        rows = [n + j for j in range(len(noise_vector)) if j >= held.size or not held[j]]
        return np.asarray(H), free + rows
    return problem.noise_term.information(problem.jacobian(theta), R), free  # rows not measured are zero


def _covariance(H: np.ndarray, keep: list, reasons: _Reasons, names) -> np.ndarray:
    """The covariance of the parameters (NaN where no std): the inverse of H on the kept rows;
    singular directions are named (not identifiable), an indefinite H is not a minimum."""
    n = len(names)
    free = [k for k in keep if k < n]
    cov = np.full((n, n), np.nan)
    if not np.all(np.isfinite(H[np.ix_(keep, keep)])):
        reasons.hold(free, StdReason.SINGULAR, "the Hessian is not finite at the estimate (the parameters' magnitudes "
                     "are far apart: give each parameter a scale= of its typical size): std not available")
        return cov
    C_keep, null = covariance_from_hessian(H[np.ix_(keep, keep)])
    # clearly negative curvature is a saddle; a tiny negative eigenvalue at a flat minimum is round-off
    if null.shape[1] and is_indefinite(H[np.ix_(keep, keep)], rcond=1e-6):
        reasons.hold(free, StdReason.NOT_A_MINIMUM,
                     "the Hessian is not positive definite here (not a minimum): std not available")
        return cov
    if null.shape[1]:
        # name the parameters in the singular directions; the rest stays conditional on them
        involved = sorted({keep[i] for i in np.flatnonzero(np.max(np.abs(null), axis=1) > 0.2) if keep[i] < n})
        involved = involved or free
        reasons.hold(involved, StdReason.NOT_IDENTIFIABLE, "not identifiable from these data: the cost is flat "
                     f"(singular Hessian) along a direction involving {[names[j] for j in involved]} "
                     f"({_combinations(null, keep, names)})")
        free = [i for i in free if i not in involved]
        keep = free + [k for k in keep if k >= n]
        C_keep, null = covariance_from_hessian(H[np.ix_(keep, keep)])
        if null.shape[1]:
            reasons.hold(free, StdReason.SINGULAR, "Hessian singular at the estimate: std not available")
            return cov
    cov[np.ix_(free, free)] = C_keep[:len(free), :len(free)]
    return cov


def _combinations(null: np.ndarray, keep: list, names) -> str:
    """The flat directions in words, e.g. ``0.71 a - 0.71 b`` (unit-scaled coordinates)."""
    words = []
    for v in null.T:
        terms = [(v[i], names[keep[i]]) for i in np.argsort(-np.abs(v)) if keep[i] < len(names) and abs(v[i]) > 0.05]
        text = " ".join(f"{'-' if c < 0 else '+'} {abs(c):.2f} {name}" for c, name in terms[:4]).lstrip("+ ")
        words.append(text if not text.startswith("- ") else "-" + text[2:])
    return "flat along " + "; ".join(words)


def _hold_unidentified(problem, theta: np.ndarray, R: np.ndarray, reasons: _Reasons, rcond: float = 1e-12) -> None:
    """Parameters the data do not determine, from the numerical null space of the Gauss-Newton
    information ``J' R^-1 J`` (the Jacobian weighted by the noise) at the estimate, in unit-scaled
    coordinates: a parameter that moves no output, or a combination along which the scaled
    information is below ``rcond`` of its largest eigenvalue, gets no std; the reason names the
    combination."""
    free = reasons.free
    if not free:
        return
    F = DIAGONAL.information(problem.jacobian(theta)[:, free], R)  # rows of outputs not measured are zero
    if not np.all(np.isfinite(F)):
        return  # the Hessian's own test names this case
    d = np.sqrt(np.diag(F))
    names = problem.model.parameter_names
    silent = [free[i] for i in np.flatnonzero(d <= 1e-150 * max(d.max(), 1e-300))]
    if silent:
        reasons.hold(silent, StdReason.NOT_IDENTIFIABLE, "not identifiable from these data: no output depends on "
                     "it at the estimate")
    live = [i for i in range(len(free)) if free[i] not in silent]
    if len(live) >= 2:
        _hold_flat_combinations(F, d, [free[i] for i in live], live, names, reasons, rcond)


def _hold_flat_combinations(F: np.ndarray, d: np.ndarray, keep: list, live: list, names, reasons: _Reasons,
                            rcond: float) -> None:
    """Hold the parameters of each combination along which the information of the ``live`` rows
    of F, scaled to unit diagonal (``d``), is below ``rcond`` of its largest (``keep``: their indices)."""
    Fn = F[np.ix_(live, live)] / np.outer(d[live], d[live])
    w, V = np.linalg.eigh(0.5 * (Fn + Fn.T))
    null = V[:, w <= rcond * w[-1]]
    if null.shape[1]:
        involved = sorted({keep[i] for i in np.flatnonzero(np.max(np.abs(null), axis=1) > 0.2)})
        reasons.hold(involved, StdReason.NOT_IDENTIFIABLE, "not identifiable from these data: the fit does not "
                     f"change along a combination of {[names[j] for j in involved]} ({_combinations(null, keep, names)}, "
                     f"scaled information below {rcond:g} of its largest)")
