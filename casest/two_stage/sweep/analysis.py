"""What the landscape says: local and competing minima, the paper's validity conditions
(Eq. 17, 18), and the checks that name unidentifiable or non-finite cases."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ...data.dataset import Dataset
from ...models import Model
from ...problem.measurement import Measurement, as_measurement
from ...problem.separate import Partition
from .candidates import design_neighbours, prior_density, sampling_distance
from .evaluators import GramEvaluator, evaluate_candidates


__all__ = ["find_local_minima", "descend_to_minimum", "profile_cost", "find_competing_minima", "validity_conditions",
           "curvature_holds_at", "project_out", "unidentifiable_linear"]


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


def descend_to_minimum(trace: np.ndarray, start: int, grid_shape, neighbours: np.ndarray | None) -> int:
    """The candidate where steepest descent over the design from ``start`` stops: each step moves to
    the lowest neighbour (grid axes, or ``neighbours`` of a scattered design) while it is strictly
    lower, so the end is not above any neighbour (a local minimum of :func:`find_local_minima`'s
    kind, or the first point of a plateau).

    Parameters
    ----------
    trace : ndarray, shape (M,)
        The ranking of the design's candidates (not finite: never a step's target).
    start : int
    grid_shape : tuple of int or None
        The grid's shape (candidates in C order), or None for a scattered design.
    neighbours : ndarray of int, shape (M, k), or None
        A scattered design's neighbours (:func:`~.candidates.design_neighbours`).

    Returns
    -------
    int
    """
    t = np.where(np.isfinite(trace), trace, np.inf)
    step = _lowest_neighbour_steps(t, grid_shape, neighbours)
    current = int(start)
    for _ in range(len(t)):
        following = int(step[current])
        if following == current:
            return current
        current = following
    return current


def _lowest_neighbour_steps(t: np.ndarray, grid_shape, neighbours: np.ndarray | None) -> np.ndarray:
    """For every candidate, its lowest neighbour where that is strictly lower, else itself (ties:
    the first in the neighbours' order: grid axes in turn, each -1 then +1), shape (M,)."""
    M = len(t)
    own = np.arange(M)
    if grid_shape is not None:
        index = own.reshape(grid_shape)
        columns = []
        for axis in range(len(grid_shape)):
            for d in (-1, 1):
                shifted = np.full(grid_shape, -1)
                source = [slice(None)] * len(grid_shape)
                target = [slice(None)] * len(grid_shape)
                source[axis] = slice(max(d, 0), grid_shape[axis] + min(d, 0))
                target[axis] = slice(max(-d, 0), grid_shape[axis] + min(-d, 0))
                shifted[tuple(target)] = index[tuple(source)]
                columns.append(shifted.reshape(-1))
        near = np.column_stack(columns) if columns else np.full((M, 0), -1)
    else:
        near = np.full((M, 0), -1) if neighbours is None else np.asarray(neighbours, dtype=int)
    if near.shape[1] == 0:
        return own
    values = np.where(near >= 0, t[np.maximum(near, 0)], np.inf)
    choice = np.argmin(values, axis=1)
    lowest = near[own, choice]
    return np.where((lowest >= 0) & (values[own, choice] < t), lowest, own)


def profile_cost(R: np.ndarray, counts) -> np.ndarray:
    """sum_j N_j/2 ln R_j: the ML cost with R at its optimum (constants dropped); ``counts`` N_j or N."""
    return 0.5 * np.sum(np.asarray(counts) * np.log(np.maximum(R, 1e-300)), axis=-1)


def ranking_values(criterion: str, R: np.ndarray, ok: np.ndarray, counts) -> np.ndarray:
    """The sweep's ranking of each candidate: Tr[R] (``"trace"``, the paper's) or the profile ML
    cost (unit-invariant); inf where A(xi2) is not of full rank.

    Parameters
    ----------
    criterion : str
        ``SweepSettings.criterion``.
    R : ndarray, shape (M, n_outputs)
    ok : ndarray of bool, shape (M,)
    counts : array_like, shape (n_outputs,)
        Measured samples per channel.

    Returns
    -------
    ndarray, shape (M,)
    """
    if criterion == "trace":
        return np.where(ok, R.sum(axis=1), np.inf)
    return np.where(ok, profile_cost(np.where(ok[:, None], R, 1.0), counts), np.inf)


def find_competing_minima(evaluator, Z, cands, R, minima, counts, confidence, bounds=(None, None), unit=None,
                          spacing: float | None = None) -> np.ndarray:
    """Minima that fit as well as the best (likelihood-ratio test) behind a real ridge.

    A local minimum is close when its profile cost N/2 ln|R| is within chi2(confidence, n2)/2
    of the best one's; a straight path between two minima has a ridge when it rises above both
    ends by more than chi2(confidence, 1)/2. First the close minima and the best are joined by
    a minimum spanning tree (in ``unit`` coordinates, the design's prior-probability space):
    a minimum reachable from the best along tree edges without a ridge lies in the best's
    basin (that polyline is a low path). The others compete when the straight path from the
    best has a ridge too. Tree edges are sampled every half ``spacing`` (the design's median
    distance between neighbours; 3 to 17 points), the straight paths at 17 points; each stage
    is evaluated in one batch. In a flat landscape with many close minima this evaluates a
    few short edges instead of a long path to every one of them.
    """
    if len(minima) < 2:
        return np.array([], dtype=int)
    n2 = cands.shape[1]
    cost = profile_cost(R[minima], counts)
    from scipy.special import chdtri  # the chi-square quantile, without importing scipy.stats

    equivalent_gap = 0.5 * chdtri(n2, 1.0 - confidence)
    ridge_gap = 0.5 * chdtri(1, 1.0 - confidence)
    best = int(minima[0])
    close = [(int(m), float(c)) for m, c in zip(minima[1:], cost[1:]) if c - cost[0] <= equivalent_gap]
    if not close:
        return np.array([], dtype=int)
    ends = {best: float(cost[0]), **dict(close)}

    def ridges(links, n_points):
        """Whether each straight path a -> b rises above both ends by more than the ridge gap."""
        paths = np.concatenate([cands[a][None, :] + np.linspace(0.0, 1.0, k + 2)[1:-1, None] * (cands[b] - cands[a])
                                for (a, b), k in zip(links, n_points)])
        _, R_path, ok = evaluate_candidates(evaluator, Z, paths, *bounds)
        path_cost = profile_cost(np.where(ok[:, None], R_path, np.inf), counts)
        split = np.split(path_cost, np.cumsum(n_points)[:-1])
        return [np.max(pc) - max(ends[a], ends[b]) > ridge_gap for (a, b), pc in zip(links, split)]

    nodes = [best] + [m for m, _ in close]
    rest = [m for m, _ in close]
    if unit is not None and len(close) > 1:
        if spacing is None:
            spacing = sampling_distance(unit)
        edges = _spanning_edges(unit[nodes])
        links = [(nodes[a], nodes[b]) for a, b in edges]
        lengths = np.array([np.linalg.norm(unit[a] - unit[b]) for a, b in links])
        n_points = np.clip(np.ceil(2.0 * lengths / max(spacing, 1e-12)) - 1, 3, 17).astype(int)
        low = [link for link, ridge in zip(links, ridges(links, n_points)) if not ridge]
        reached = _reachable(best, low)
        rest = [m for m in rest if m not in reached]
    if not rest:
        return np.array([], dtype=int)
    direct = ridges([(best, m) for m in rest], [17] * len(rest))
    return np.array([m for m, ridge in zip(rest, direct) if ridge], dtype=int)


def _spanning_edges(points: np.ndarray) -> list[tuple[int, int]]:
    """The edges (parent, child) of a minimum spanning tree of ``points`` (Prim, rooted at point 0)."""
    n = len(points)
    in_tree = np.zeros(n, dtype=bool)
    in_tree[0] = True
    distance = np.linalg.norm(points - points[0], axis=1)
    parent = np.zeros(n, dtype=int)
    edges = []
    for _ in range(n - 1):
        j = int(np.argmin(np.where(in_tree, np.inf, distance)))
        edges.append((int(parent[j]), j))
        in_tree[j] = True
        nearer = np.linalg.norm(points - points[j], axis=1) < distance
        distance[nearer] = np.linalg.norm(points[nearer] - points[j], axis=1)
        parent[nearer] = j
    return edges


def _reachable(root: int, links) -> set:
    """The nodes joined to ``root`` by the undirected ``links``."""
    neighbours: dict = {}
    for a, b in links:
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    seen, stack = {root}, [root]
    while stack:
        for nxt in neighbours.get(stack.pop(), []):
            if nxt not in seen:
                seen.add(nxt)
                stack.append(nxt)
    return seen


# ----------------------------------------------------------------------------- Eq. 17, 18
#: samples per block of the validity checks (bounded memory whatever N is)
VALIDITY_BLOCK = 8192


def validity_conditions(
    model: Model | Measurement, partition: Partition, data: Dataset, xi1: np.ndarray, xi2: np.ndarray, step: np.ndarray,
    R: np.ndarray | None = None, density: np.ndarray | None = None,
) -> tuple[float, float, list[str], float]:
    """Eq. 17 ratio, Eq. 18 smallest normalised eigenvalue, the weakest xi2 names, flat spread.

    ``R`` (per channel) weights the profile information; ``density`` (prior densities of
    xi2 at the candidate, shape (n2,)) turns its weakest direction into prior-CDF units:
    the returned spread is the one-sigma interval of that direction there (``inf`` when
    the information is singular).
    """
    theta = partition.assemble(xi1, xi2)
    order = list(partition.linear_index) + list(partition.nonlinear_index)  # [J1 J2]
    n1 = partition.n_linear
    weights = None if R is None or density is None else 1.0 / np.sqrt(np.maximum(np.asarray(R, dtype=float), 1e-300))
    squares = np.zeros(2)  # ||h||^2 and ||J2 step||^2
    triangle = np.zeros((0, len(order)))
    weighted = np.zeros((0, len(order)))
    # blocks of samples: the R factors of [J1 J2] (unweighted, and weighted by 1/sqrt(R_j)) are
    # carried from block to block, so the record's Jacobian is never held at once
    for h, J, mask in as_measurement(model).prediction_blocks(theta, data, VALIDITY_BLOCK):
        h, J = h * mask, J[:, order] * mask[:, None]  # outputs not measured leave the checks
        squares += [h @ h, np.sum((J[:, n1:] @ step) ** 2)]
        triangle = np.linalg.qr(np.vstack([triangle, J]), mode="r")
        if weights is not None:
            weighted = np.linalg.qr(np.vstack([weighted, J * np.tile(weights, h.size // weights.size)[:, None]]),
                                    mode="r")
    ratio = float(math.sqrt(squares[1]) / max(math.sqrt(squares[0]), 1e-300))
    P = _projected_gram(triangle, n1)  # J2p' J2p with J2p = J2 without the span of J1's columns
    spread = math.inf
    if weights is not None:
        # the same projection with each channel weighted by 1/R_j: the profile Fisher information
        info_u = _projected_gram(weighted, n1) / np.outer(density, density)
        lam = np.linalg.eigvalsh(0.5 * (info_u + info_u.T))[0] if np.all(density > 0) else 0.0
        spread = float(1.0 / math.sqrt(lam)) if lam > 0 else math.inf
    d = np.sqrt(np.diag(P))
    if np.any(d == 0):
        return ratio, 0.0, [partition.nonlinear[i] for i in np.flatnonzero(d == 0)], spread
    Pn = P / np.outer(d, d)
    w, V = np.linalg.eigh(Pn)
    weak = [partition.nonlinear[i] for i in np.flatnonzero(np.abs(V[:, 0]) > 0.3)]
    return ratio, float(w[0]), weak, spread


def curvature_holds_at(measurement: Measurement, partition: Partition, data: Dataset, theta: np.ndarray,
                       curvature_tol: float, flat_spread: float) -> bool:
    """Whether the curvature check (paper Eq. 18, as the sweep's verdict applies it) holds at ``theta``:
    the smallest normalised eigenvalue of the profile Gauss-Newton matrix in xi2 at least
    ``curvature_tol`` and the one-sigma interval of its worst-determined combination at most
    ``flat_spread`` of the swept prior mass, with R the residuals' mean squares there.

    Stage 1 judges it at the best candidate, which on a coarse design can sit where a term of the
    model is misplaced and xi2 looks undetermined; at a converged solution it says whether the
    data determine xi2 there.

    Parameters
    ----------
    measurement : Measurement
    partition : Partition
    data : Dataset
        The sweep's data.
    theta : ndarray, shape (n_parameters,)
    curvature_tol, flat_spread : float
        :class:`~.settings.SweepSettings`' tau_2 and flat spread.

    Returns
    -------
    bool
    """
    theta = np.asarray(theta, dtype=float)
    xi1, xi2 = theta[list(partition.linear_index)], theta[list(partition.nonlinear_index)]
    residuals = (data.filled_outputs() - measurement.predict(theta, data)) * data.output_mask()
    R = np.sum(residuals ** 2, axis=0) / np.maximum(data.observed_counts(), 1)
    params = [measurement.model.parameters[i] for i in partition.nonlinear_index]
    _, eig, _, spread = validity_conditions(measurement, partition, data, xi1, xi2, np.zeros(len(xi2)), R,
                                            prior_density(params, xi2))
    return bool(eig >= curvature_tol and spread <= flat_spread)


def _projected_gram(triangle: np.ndarray, n1: int) -> np.ndarray:
    """``J2p' J2p`` from the R factor of ``[J1 J2]`` (J1: the first ``n1`` columns): R22' R22."""
    R22 = triangle[n1:, n1:]
    return R22.T @ R22


def project_out(J1: np.ndarray, J2: np.ndarray) -> np.ndarray:
    """J2 with the span of J1's columns removed (the profile over the linear parameters)."""
    if not J1.shape[1]:
        return J2
    Q, _ = np.linalg.qr(J1)
    return J2 - Q @ (Q.T @ J2)


def unidentifiable_linear(evaluator, cand: np.ndarray, names: Sequence[str]) -> list[str]:
    evaluator = evaluator.bulk if isinstance(evaluator, GramEvaluator) else evaluator
    A, _ = evaluator(cand[None, :])
    A = A[0]
    norms = np.linalg.norm(A, axis=0)
    if np.any(norms == 0):
        return [names[i] for i in np.flatnonzero(norms == 0)]
    _, _, Vt = np.linalg.svd(A / norms, full_matrices=False)
    return [names[i] for i in np.flatnonzero(np.abs(Vt[-1]) > 0.3)]
