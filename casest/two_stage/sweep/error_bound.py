"""The paper's own stage-1 quantities: the cost error E and the bracket of Eq. 7-13, and the
validity conditions Eq. 17 and 18 as the paper writes them (Sec. II.A-C).

Eq. 7 brackets the optimal cost by the stage-1 cost at the best candidate xi2p:

    J(xi1p, xi2p) - E  <=  J*  <=  J(xi1p, xi2p),

with (Eq. 9, the maximum over xi1 taken by Cauchy-Schwarz as in Eq. 11)

    E = 1/2 max_{xi2 in S} sum_k ( eps1 ||A_k(xi2) - A_k(xi2p)|| + ||b_k(xi2) - b_k(xi2p)|| )^2

over the swept set S, norms weighted by R(xi2p)^-1/2 (the paper drops the subscript R);
eps1 bounds ||xi1||. Eq. 11-12 bound each term by its largest value over the samples
(E_eps = N/2 (eps_A + eps_b)^2), Eq. 13 by the Lipschitz constants of A and b over S
(E_lip = N/2 (L_A eps1 eps2 + L_b eps2)^2, eps2 = max ||xi2 - xi2p|| over S). The three
are ordered E <= E_eps <= E_lip. With several channels the matrix norm is Frobenius'
(an upper bound of the spectral norm, so the bracket stays a bound).

Eq. 17 (the first-order terms of Eq. 15 relative to A and b): ||dA/dxi2 dxi2|| / ||A(xi2p)||
and ||db/dxi2 dxi2|| / ||b(xi2p)||, each to be at most tau_1, dxi2 the sweep's half step.
Eq. 18: sum_k (d(A_k xi1p)/dxi2)^T (d(A_k xi1p)/dxi2) and sum_k (db_k/dxi2)^T (db_k/dxi2)
positive definite; reported as the smallest eigenvalue of each, normalised to unit diagonal.
The derivatives are central differences of A and b (relative step 1e-6).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ...backend.array_sums import ArrayProgram, ArrayValues


__all__ = ["ErrorBound", "paper_error_bound", "BRACKET_SIDES"]

#: Where the stage-2 optimum J* fell against the bracket of Eq. 7.
BRACKET_SIDES = {
    "inside": "J(xi1p, xi2p) - E <= J* <= J(xi1p, xi2p), as Eq. 7 states",
    "below": "J* is below the lower end J(xi1p, xi2p) - E: the bound of Eq. 9 does not hold here",
    "above": "J* is above the stage-1 cost J(xi1p, xi2p): stage 2 ended worse than its start",
}


@dataclass
class ErrorBound:
    """The paper's cost error E, its bounds and Eq. 17-18 at the best stage-1 candidate.

    Attributes
    ----------
    stage1_cost : float
        J(xi1p, xi2p): the ML cost (constants as in :attr:`casest.Estimate.cost`) at the best
        candidate with R its residual mean square.
    E : float
        The cost error of Eq. 9 over the swept set (see the module docstring).
    E_eps : float
        Eq. 11-12: N/2 (eps_A + eps_b)^2.
    E_lipschitz : float
        Eq. 13: N/2 (L_A eps1 eps2 + L_b eps2)^2, with the Lipschitz constants estimated
        as the largest secant slopes over the swept set.
    eps1, eps2 : float
        Bound of ||xi1|| (the box of xi1 if finite, else the largest least-squares xi1 of
        the sweep; ``eps1_source`` says which) and largest ||xi2 - xi2p|| over the set.
    eps_A, eps_b, L_A, L_b : float
        The terms of Eq. 11-13 (weighted norms).
    eps1_source : str
        ``"bounds"`` or ``"sweep"``.
    n_candidates : int
        Size of the swept set S.
    eq17_A, eq17_b : float
        The two ratios of Eq. 17 (``nan`` when A or b is zero at xi2p).
    eq18_A, eq18_b : float
        Smallest normalised eigenvalue of the two matrices of Eq. 18 (0 when a column is zero;
        ``nan`` when the term does not depend on xi2 at all, as b = 0: not applicable).
    comparable : bool
        Whether the stage-2 optimum of the estimate is a J* of the same cost: False when stage 1
        ran on other data (``stage1_data``) or the noise model is not the unknown diagonal R.
    """

    stage1_cost: float
    E: float
    E_eps: float
    E_lipschitz: float
    eps1: float
    eps2: float
    eps_A: float
    eps_b: float
    L_A: float
    L_b: float
    eps1_source: str
    n_candidates: int
    eq17_A: float
    eq17_b: float
    eq18_A: float
    eq18_b: float
    comparable: bool = True

    @classmethod
    def from_dict(cls, data: dict) -> "ErrorBound":
        """The ErrorBound of its fields as saved (non-finite numbers written as strings).

        Parameters
        ----------
        data : dict
            Field name -> value (a result file's ``error_bound``).

        Returns
        -------
        ErrorBound
        """
        return cls(**{k: float(v) if isinstance(v, str) and k != "eps1_source" else v for k, v in data.items()})

    @property
    def lower(self) -> float:
        """The lower end of the bracket, J(xi1p, xi2p) - E."""
        return self.stage1_cost - self.E

    def side(self, cost: float, rtol: float = 1e-9) -> str:
        """Where a stage-2 optimum ``cost`` falls: a key of :data:`BRACKET_SIDES`.

        Parameters
        ----------
        cost : float
            J* in the convention of :attr:`casest.Estimate.cost`.
        rtol : float
            Relative tolerance of the comparisons (rounding of the two costs).

        Returns
        -------
        str
            ``"inside"``, ``"below"`` or ``"above"``.
        """
        slack = rtol * max(1.0, abs(self.stage1_cost))
        if cost > self.stage1_cost + slack:
            return "above"
        if cost < self.lower - slack:
            return "below"
        return "inside"

    def lines(self) -> list[str]:
        """Report lines (the bracket, E and its two bounds, Eq. 17 and 18 as printed).

        Returns
        -------
        list of str
        """
        return [
            f"error bound (paper Eq. 7-13): J(xi1p, xi2p) = {self.stage1_cost:.8g}, E = {self.E:.4g} over "
            f"{self.n_candidates} candidates (eps1 = {self.eps1:.4g} from the {self.eps1_source}, eps2 = "
            f"{self.eps2:.4g}); Eq. 11-12 bound {self.E_eps:.4g}, Eq. 13 Lipschitz bound {self.E_lipschitz:.4g}",
            f"paper Eq. 17 as printed: ||dA dxi2|| / ||A|| = {_shown(self.eq17_A, 'A = 0')}, ||db dxi2|| / ||b|| = "
            f"{_shown(self.eq17_b, 'b = 0')}; Eq. 18 as printed: smallest normalised eigenvalues "
            f"{_shown(self.eq18_A, 'A xi1p does not depend on xi2')} (A xi1p), "
            f"{_shown(self.eq18_b, 'b does not depend on xi2')} (b)",
        ]

    @property
    def vacuous(self) -> bool:
        """Whether the bracket says nothing: E exceeds the magnitude of the cost it brackets."""
        return bool(self.E > abs(self.stage1_cost))

    def verdict(self, cost: float) -> str:
        """What the bracket says of a stage-2 optimum ``cost``: a line for reports.

        Parameters
        ----------
        cost : float
            J* in the convention of :attr:`casest.Estimate.cost`.

        Returns
        -------
        str
        """
        said = BRACKET_SIDES[self.side(cost)]
        if self.vacuous:
            said += (f"; but the bracket is vacuous: E = {self.E:.3g} exceeds |J(xi1p, xi2p)| = "
                     f"{abs(self.stage1_cost):.4g}, so Eq. 7 gives no information about J* here (the swept set is "
                     "too wide for the paper's bound)")
        return said


def paper_error_bound(evaluator, data, candidates: np.ndarray, xi1: np.ndarray, R: np.ndarray, best: int,
                      step: np.ndarray, linear_bounds=(None, None)) -> ErrorBound:
    """E, its bounds and Eq. 17-18 at candidate ``best`` of a sweep.

    Parameters
    ----------
    evaluator : BulkEvaluator or DynamicBulkEvaluator
        A and b of candidates over the data (``A`` of shape (M, N n_y, n1)).
    data : Dataset
        The swept data (its output mask).
    candidates : ndarray, shape (M, n2)
        The swept set S.
    xi1 : ndarray, shape (M, n1)
        Least-squares xi1 per candidate (NaN where A was rank-deficient).
    R : ndarray, shape (M, n_y)
        Per-channel residual mean square per candidate.
    best : int
        Index of xi2p.
    step : ndarray, shape (n2,)
        The half sweep step dxi2 of Eq. 17.
    linear_bounds : (lb, ub) of shape (n1,) or (None, None)
        The box of xi1: when finite it gives eps1.

    Returns
    -------
    ErrorBound
    """
    counts = np.asarray(data.observed_counts(), dtype=float)
    Rp = np.maximum(np.asarray(R[best], dtype=float), 1e-300)
    weight = data.output_mask().reshape(-1) * np.tile(1.0 / np.sqrt(Rp), data.n_samples)
    eps1, source = _eps1(xi1, linear_bounds)
    Ap, bp = evaluator(candidates[best][None, :])
    terms = _swept_terms(evaluator, candidates, best, Ap[0], bp[0], weight, eps1, data.n_samples, R.shape[1])
    eps_A, eps_b = np.float64(eps1) * terms["max_A"], np.float64(terms["max_b"])
    N = data.n_samples
    with np.errstate(over="ignore", invalid="ignore"):  # an unbounded xi1 gives inf, not an error
        E_eps = float(0.5 * N * (eps_A + eps_b) ** 2)
        E_lipschitz = float(0.5 * N * (terms["L_A"] * np.float64(eps1) * terms["eps2"] + terms["L_b"] * terms["eps2"]) ** 2)
    eq17, eq18 = _paper_conditions(evaluator, candidates[best], xi1[best], step, Ap[0], bp[0],
                                   data.output_mask().reshape(-1))
    return ErrorBound(
        stage1_cost=float(0.5 * np.sum(counts * (1.0 + np.log(Rp)))), E=0.5 * terms["max_sum"],
        E_eps=E_eps, E_lipschitz=E_lipschitz, eps1=eps1, eps2=terms["eps2"], eps_A=float(eps_A), eps_b=float(eps_b),
        L_A=terms["L_A"], L_b=terms["L_b"],
        eps1_source=source, n_candidates=len(candidates), eq17_A=eq17[0], eq17_b=eq17[1], eq18_A=eq18[0],
        eq18_b=eq18[1],
    )


def _eps1(xi1: np.ndarray, linear_bounds) -> tuple[float, str]:
    """The bound of ||xi1||: the corner of a finite box, else the sweep's largest least-squares xi1."""
    lb, ub = linear_bounds
    if lb is not None and np.all(np.isfinite(lb)) and np.all(np.isfinite(ub)):
        return float(np.linalg.norm(np.maximum(np.abs(lb), np.abs(ub)))), "bounds"
    finite = np.all(np.isfinite(xi1), axis=1)
    return (float(np.max(np.linalg.norm(xi1[finite], axis=1))) if finite.any() else math.inf), "sweep"


def _swept_terms(evaluator, candidates, best, Ap, bp, weight, eps1, N, ny) -> dict:
    """The maxima over S of the per-sample differences, summed (E) and single (Eq. 11-13)."""
    out = {"max_sum": 0.0, "max_A": 0.0, "max_b": 0.0, "L_A": 0.0, "L_b": 0.0, "eps2": 0.0}
    squares = _squared_differences(evaluator, Ap, bp, weight, N, ny)
    block = max(1, int(getattr(evaluator, "chunk", 1)))
    for start in range(0, len(candidates), block):
        cands = candidates[start:start + block]
        sq_A, sq_b = squares(cands)
        norm_A, norm_b = np.sqrt(sq_A), np.sqrt(sq_b)  # (M, N): Frobenius (the 2-norm with one channel)
        # a candidate with a NaN or infinite term anywhere is left out: its row maxima are not finite
        peak_A, peak_b = norm_A.max(axis=1), norm_b.max(axis=1)
        finite = np.isfinite(peak_A) & np.isfinite(peak_b)
        if not finite.any():
            continue
        if not finite.all():
            norm_A, norm_b, peak_A, peak_b = norm_A[finite], norm_b[finite], peak_A[finite], peak_b[finite]
            cands = cands[finite]
        with np.errstate(over="ignore", invalid="ignore"):
            out["max_sum"] = max(out["max_sum"], float(np.max(np.sum((eps1 * norm_A + norm_b) ** 2, axis=1))))
        out["max_A"] = max(out["max_A"], float(peak_A.max()))
        out["max_b"] = max(out["max_b"], float(peak_b.max()))
        distance = np.linalg.norm(cands - candidates[best], axis=1)
        out["eps2"] = max(out["eps2"], float(distance.max()))
        away = distance > 0
        if away.any():
            out["L_A"] = max(out["L_A"], float(np.max(peak_A[away] / distance[away])))
            out["L_b"] = max(out["L_b"], float(np.max(peak_b[away] / distance[away])))
    return out


def _squared_differences(evaluator, Ap, bp, weight, N, ny):
    """``cands -> (||W (A_k - Ap_k)||_F^2, ||W (b_k - bp_k)||^2)``, each (M, N).

    Where the evaluator runs NumPy operations (nothing compiled), the differences are one
    program of their own (:class:`~casest.backend.array_sums.ArrayValues` of a per-sample
    function), so A and b never fill memory; else from the evaluator's A and b."""
    w2 = (weight ** 2).reshape(N, ny)
    if getattr(evaluator, "uncompiled_arrays", False):
        program = _difference_program(evaluator.partition, evaluator.signals, Ap, bp, w2)
        if program is not None:
            return lambda cands: tuple(np.moveaxis(program(cands), 2, 0))

    def from_A_and_b(cands):
        A, b = evaluator(cands)
        M = len(cands)
        dA = (A - Ap[None]).reshape(M, N, ny, -1)
        db = (b - bp[None]).reshape(M, N, ny)
        # squares summed over xi1 first, then weighted per channel
        return np.einsum("mkj,kj->mk", np.einsum("mkji,mkji->mkj", dA, dA), w2), np.einsum("mkj,kj->mk", db * db, w2)

    return from_A_and_b


def _difference_program(partition, signals, Ap, bp, w2):
    """The per-sample squared differences to xi2p's A and b as NumPy operations, or None."""
    ny, n1 = w2.shape[1], partition.n_linear
    key = ("error_bound_squares", signals.shape[1], ny)
    per_sample, program = partition.builds.get_or_build(key, lambda: _squares_program(partition, *key[1:]))
    if program is None:
        return None
    N = signals.shape[0]
    Ap_k = Ap.reshape(N, ny, n1).transpose(0, 2, 1).reshape(N, ny * n1)  # row k: vec of sample k's (ny, n1) block
    refs = np.hstack([Ap_k, bp.reshape(N, ny), w2])
    return ArrayValues.build(per_sample, [signals, refs], program)


def _squares_program(partition, n_signals: int, ny: int) -> tuple:
    """The per-sample squared differences to reference A and b (an SX function) and its array
    program; None for either where they have no such form."""
    n1 = partition.n_linear
    x, xi2 = ca.SX.sym("x", n_signals), ca.SX.sym("xi2", partition.n_nonlinear)
    ref = ca.SX.sym("ref", ny * n1 + 2 * ny)  # per sample: vec(Ap_k) column-major, bp_k, the weights squared
    try:
        A = partition.A(x, xi2) if n1 else ca.SX(ny, 0)
        b = partition.b(x, xi2)
    except RuntimeError:  # A or b not expressible on SX symbols
        return None, None
    dA = A - ca.reshape(ref[: ny * n1], ny, n1)
    db = b - ref[ny * n1: ny * n1 + ny]
    w = ref[ny * n1 + ny:]
    sq_A = ca.dot(w, ca.sum2(dA * dA)) if n1 else ca.SX(0)
    per_sample = ca.Function("error_bound_squares", [x, ref, xi2], [ca.densify(ca.vertcat(sq_A, ca.dot(w, db * db)))])
    return per_sample, ArrayProgram.of(per_sample, 2)


def _paper_conditions(evaluator, xi2p, xi1p, step, Ap, bp, mask) -> tuple:
    """Eq. 17's two ratios and Eq. 18's two smallest normalised eigenvalues at xi2p."""
    n2 = len(xi2p)
    h = 1e-6 * np.maximum(np.abs(xi2p), 1.0)
    probes = np.vstack([xi2p + np.diag(h), xi2p - np.diag(h)])
    block = max(1, int(getattr(evaluator, "chunk", 1)))  # an evaluator takes at most its chunk per call
    parts = [evaluator(probes[k:k + block]) for k in range(0, len(probes), block)]
    A, b = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    dA = (A[:n2] - A[n2:]) / (2 * h)[:, None, None] * mask[None, :, None]  # (n2, N n_y, n1)
    db = (b[:n2] - b[n2:]) / (2 * h)[:, None] * mask[None, :]
    Ap, bp = Ap * mask[:, None], bp * mask
    ratio_A = _ratio(np.tensordot(step, dA, axes=1), Ap)
    ratio_b = _ratio(np.tensordot(step, db, axes=1), bp)
    xi1p = np.where(np.isfinite(xi1p), xi1p, 0.0)
    # a term that does not depend on xi2 at all (b = 0, say) has no Eq. 18 matrix: not applicable, not 0
    eq18_A = _min_normalised_eig((dA @ xi1p).T) if np.any(dA @ xi1p) else math.nan
    eq18_b = _min_normalised_eig(db.T) if np.any(db) else math.nan
    return (ratio_A, ratio_b), (eq18_A, eq18_b)


def _shown(value: float, why_not: str) -> str:
    """A number for the report, or why it does not apply."""
    return f"{value:.3g}" if np.isfinite(value) else f"not applicable ({why_not})"


def _ratio(change: np.ndarray, base: np.ndarray) -> float:
    norm = float(np.linalg.norm(base))
    return float(np.linalg.norm(change) / norm) if norm > 0 else math.nan


def _min_normalised_eig(columns: np.ndarray) -> float:
    """Smallest eigenvalue of columns^T columns scaled to unit diagonal (0 when a column is zero)."""
    G = columns.T @ columns
    d = np.sqrt(np.diag(G))
    if G.size == 0 or np.any(d == 0):
        return 0.0
    return float(np.linalg.eigvalsh(G / np.outer(d, d))[0])
