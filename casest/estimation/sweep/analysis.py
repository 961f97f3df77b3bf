"""What the landscape says: local and competing minima, the paper's validity conditions
(Eq. 17, 18), and the checks that name unidentifiable or non-finite cases."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ...data.dataset import Dataset
from ...models import Model, ModelError
from ...problem.measurement import measurement_of
from ..separate import Partition
from .candidates import design_neighbours
from .evaluators import GramEvaluator, evaluate_candidates


__all__ = ["find_local_minima", "profile_cost", "find_competing_minima", "validity_conditions", "project_out", "check_predictions", "unidentifiable_linear"]


def find_local_minima(unit: np.ndarray, trace: np.ndarray, grid_shape, neighbours: np.ndarray | None = None
                      ) -> np.ndarray:
    """Indices of candidates not above any neighbour (grid axes, or the ``2 n2 + 2`` nearest in ``unit``:
    ``neighbours`` as :func:`~.candidates.design_neighbours` gives them, computed when not given)."""
    M, n2 = unit.shape
    if M == 1:
        return np.array([0])
    t = np.where(np.isfinite(trace), trace, np.inf)
    if grid_shape is not None:
        grid = t.reshape(grid_shape)
        is_min = np.isfinite(grid)
        for axis in range(n2):
            for shift in (1, -1):
                neighbour = np.roll(grid, shift, axis=axis)
                edge = [slice(None)] * n2
                edge[axis] = 0 if shift == 1 else -1
                neighbour[tuple(edge)] = np.inf
                is_min &= grid <= neighbour
        idx = np.flatnonzero(is_min.reshape(-1))
    else:
        nb = design_neighbours(unit) if neighbours is None else neighbours
        idx = np.flatnonzero(np.isfinite(t) & (t <= t[nb].min(axis=1)))
    return idx[np.argsort(t[idx], kind="stable")]


def profile_cost(R: np.ndarray, counts) -> np.ndarray:
    """sum_j N_j/2 ln R_j: the ML cost with R at its optimum (constants dropped); ``counts`` N_j or N."""
    return 0.5 * np.sum(np.asarray(counts) * np.log(np.maximum(R, 1e-300)), axis=-1)


def find_competing_minima(evaluator, Z, cands, R, minima, counts, confidence, bounds=(None, None)) -> np.ndarray:
    """Minima that fit as well as the best (likelihood-ratio test) behind a real ridge.

    A local minimum competes when its profile cost N/2 ln|R| is within
    chi2(confidence, n2)/2 of the best one's and the straight path between them rises
    above both ends by more than chi2(confidence, 1)/2. All paths are evaluated in one
    batch.
    """
    if len(minima) < 2:
        return np.array([], dtype=int)
    n2 = cands.shape[1]
    cost = profile_cost(R[minima], counts)
    from scipy.special import chdtri  # the chi-square quantile, without importing scipy.stats

    equivalent_gap = 0.5 * chdtri(n2, 1.0 - confidence)
    ridge_gap = 0.5 * chdtri(1, 1.0 - confidence)
    best = minima[0]
    close = [(m, c) for m, c in zip(minima[1:], cost[1:]) if c - cost[0] <= equivalent_gap]
    if not close:
        return np.array([], dtype=int)
    fractions = np.linspace(0.0, 1.0, 19)[1:-1]
    paths = np.concatenate(
        [cands[best][None, :] + fractions[:, None] * (cands[m] - cands[best])[None, :] for m, _ in close]
    )
    _, R_path, ok = evaluate_candidates(evaluator, Z, paths, *bounds)
    path_cost = profile_cost(np.where(ok[:, None], R_path, np.inf), counts).reshape(len(close), -1)
    competing = [m for (m, c), pc in zip(close, path_cost) if np.max(pc) - max(cost[0], c) > ridge_gap]
    return np.array(competing, dtype=int)


# ----------------------------------------------------------------------------- Eq. 17, 18
def validity_conditions(
    model: Model, partition: Partition, data: Dataset, xi1: np.ndarray, xi2: np.ndarray, step: np.ndarray,
    R: np.ndarray | None = None, density: np.ndarray | None = None,
) -> tuple[float, float, list[str], float]:
    """Eq. 17 ratio, Eq. 18 smallest normalised eigenvalue, the weakest xi2 names, flat spread.

    ``R`` (per channel) weights the profile information; ``density`` (prior densities of
    xi2 at the candidate, shape (n2,)) turns its weakest direction into prior-CDF units:
    the returned spread is the one-sigma interval of that direction there (``inf`` when
    the information is singular).
    """
    theta = partition.assemble(xi1, xi2)
    xi2_idx = list(partition.nonlinear_index)
    h, J = measurement_of(model).prediction_and_jacobian(theta, data)  # a dynamic model's: through the states
    mask = data.output_mask().reshape(-1)  # outputs not measured leave the checks
    h, J = h * mask, J * mask[:, None]
    J2 = J[:, xi2_idx]
    J1 = J[:, list(partition.linear_index)]
    ratio = float(np.linalg.norm(J2 @ step) / max(np.linalg.norm(h), 1e-300))
    J2p = project_out(J1, J2)
    P = J2p.T @ J2p
    spread = math.inf
    if R is not None and density is not None:
        # the same projection with each channel weighted by 1/R_j: the profile Fisher information
        w = np.tile(1.0 / np.sqrt(np.maximum(np.asarray(R, dtype=float), 1e-300)), data.n_samples)
        J2w = project_out(J1 * w[:, None], J2 * w[:, None])
        info_u = (J2w.T @ J2w) / np.outer(density, density)
        lam = np.linalg.eigvalsh(0.5 * (info_u + info_u.T))[0] if np.all(density > 0) else 0.0
        spread = float(1.0 / math.sqrt(lam)) if lam > 0 else math.inf
    d = np.sqrt(np.diag(P))
    if np.any(d == 0):
        return ratio, 0.0, [partition.nonlinear[i] for i in np.flatnonzero(d == 0)], spread
    Pn = P / np.outer(d, d)
    w, V = np.linalg.eigh(Pn)
    weak = [partition.nonlinear[i] for i in np.flatnonzero(np.abs(V[:, 0]) > 0.3)]
    return ratio, float(w[0]), weak, spread


def project_out(J1: np.ndarray, J2: np.ndarray) -> np.ndarray:
    """J2 with the span of J1's columns removed (the profile over the linear parameters)."""
    if not J1.shape[1]:
        return J2
    Q, _ = np.linalg.qr(J1)
    return J2 - Q @ (Q.T @ J2)


def check_predictions(model: Model, data: Dataset, theta: np.ndarray, label: str) -> None:
    """Raise a :class:`ModelError` naming the output and samples where the model is NaN or infinite.

    Parameters
    ----------
    model : Model or DynamicModel
    data : Dataset
    theta : ndarray, shape (n_parameters,)
    label : str
        What ``theta`` is, for the message (e.g. "nominal values").

    Returns
    -------
    None
        Returns only when every prediction is finite.

    Raises
    ------
    ModelError
        Naming the output, the rows and the signals of the first bad row.
    """
    with np.errstate(all="ignore"):
        pred = measurement_of(model).predict(theta, data)
    bad = ~np.isfinite(pred)
    if not bad.any():
        return
    j = int(np.flatnonzero(bad.any(axis=0))[0])
    rows = np.flatnonzero(bad[:, j])
    shown = ", ".join(str(r) for r in rows[:5]) + (" ..." if rows.size > 5 else "")
    where = ", ".join(f"{n} = {v:.6g}" for n, v in zip(model.signal_names, data.signals[rows[0]]))
    raise ModelError(
        f"output {model.output_names[j]!r} is NaN or infinite at {rows.size} of {data.n_samples} samples (rows "
        f"{shown}, 0-based) at the {label}; at row {rows[0]}: {where or 'no signals'}. The model is not defined "
        "there (a log or sqrt of a negative number, a division by zero?): drop those samples, or change the model "
        f"or the {label}"
    )


def unidentifiable_linear(evaluator, cand: np.ndarray, names: Sequence[str]) -> list[str]:
    evaluator = evaluator.bulk if isinstance(evaluator, GramEvaluator) else evaluator
    A, _ = evaluator(cand[None, :])
    A = A[0]
    norms = np.linalg.norm(A, axis=0)
    if np.any(norms == 0):
        return [names[i] for i in np.flatnonzero(norms == 0)]
    _, _, Vt = np.linalg.svd(A / norms, full_matrices=False)
    return [names[i] for i in np.flatnonzero(np.abs(Vt[-1]) > 0.3)]
