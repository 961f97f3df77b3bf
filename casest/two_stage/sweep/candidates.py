"""Where stage 1 samples xi2: grid, Sobol or random draws from the priors; neighbourhoods and
local refinements in prior-probability coordinates."""

from __future__ import annotations

import functools
import hashlib
import math
import threading

import numpy as np

from ..._casadi.memory import register_memory_cache
from ...errors import OptionError
from ...models import Model
from ...problem.separate import Partition
from .settings import SweepSettings


__all__ = ["DESIGNS", "draw_candidates", "check_sweep_memory", "to_unit", "nearest_neighbours", "design_neighbours", "sampling_distance", "prior_density", "local_design", "half_step"]


# ----------------------------------------------------------------------------- design
def draw_candidates(
    model: Model, partition: Partition, settings: SweepSettings = SweepSettings()
) -> tuple[np.ndarray, str, tuple | None]:
    """Draw xi2 candidates from the parameters' priors, truncated to their bounds.

    Parameters
    ----------
    model : Model or DynamicModel
    partition : Partition
        Which parameters are xi2.
    settings : SweepSettings
        ``design``, ``n_candidates`` and ``seed``.

    Returns
    -------
    candidates : ndarray, shape (M, n2)
    design : str
        The design used (``auto`` resolved).
    grid_shape : tuple of int or None
    """
    params = [model.parameters[i] for i in partition.nonlinear_index]
    n2 = len(params)
    if n2 == 0:
        return np.zeros((1, 0)), "none", None
    check_sweep_memory(settings.n_candidates, partition, model.n_outputs)
    # "auto": a grid while it stays dense enough, a Sobol sequence beyond two dimensions
    design = settings.design if settings.design != "auto" else ("grid" if n2 <= 2 else "sobol")
    cands, grid_shape = DESIGNS[design](params, settings)
    return cands, design, grid_shape


def _grid_design(params: list, settings: SweepSettings) -> tuple:
    """A full grid of about ``n_candidates`` points, equally spaced in prior probability (ends
    included where the prior's support is finite in the box)."""
    n2 = len(params)
    per_dim = max(2, int(math.floor(settings.n_candidates ** (1.0 / n2) + 1e-9)))
    axes = []
    for p in params:
        prior = p.sampling_prior
        u = np.linspace(0.0, 1.0, per_dim) if prior.finite_support(p.lb, p.ub) else (np.arange(per_dim) + 0.5) / per_dim
        axes.append(prior.ppf(u, p.lb, p.ub))
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.column_stack([m.reshape(-1) for m in mesh]), tuple([per_dim] * n2)


def _sobol_design(params: list, settings: SweepSettings) -> tuple:
    """The first ``n_candidates`` points of a (scrambled, with a seed) Sobol sequence, mapped
    through the priors."""
    n2 = len(params)
    m = max(1, int(math.ceil(math.log2(settings.n_candidates))))
    seed = settings.seed if isinstance(settings.seed, (int, np.integer)) else None
    u = (_sobol_points(n2, m, int(seed)) if seed is not None else _scrambled_sobol(n2, m, settings.seed))
    return _through_priors(params, u[: settings.n_candidates]), None


def _random_design(params: list, settings: SweepSettings) -> tuple:
    """``n_candidates`` independent draws from the priors."""
    u = np.random.default_rng(settings.seed).random((settings.n_candidates, len(params)))
    return _through_priors(params, u), None


def _through_priors(params: list, u: np.ndarray) -> np.ndarray:
    """Points of the unit cube as parameter values (each column through its prior's quantiles)."""
    return np.column_stack([p.sampling_prior.ppf(u[:, j], p.lb, p.ub) for j, p in enumerate(params)])


#: the stage-1 designs by name (``SweepSettings.design``; ``"auto"`` picks one of them), each
#: giving (candidates (M, n2), the grid's shape or None) for the swept parameters
DESIGNS = {"grid": _grid_design, "sobol": _sobol_design, "random": _random_design}


def scrambled_sobol_rows(n2: int, seed: int, start: int, stop: int) -> np.ndarray:
    """Rows ``start:stop`` of the scrambled Sobol sequence of ``seed`` (those of
    :func:`_scrambled_sobol`), without drawing the rows before them.

    Parameters
    ----------
    n2 : int
        Dimensions.
    seed : int
    start, stop : int

    Returns
    -------
    ndarray, shape (stop - start, n2)
        Points in [0, 1)^n2.
    """
    from scipy.stats import qmc

    engine = qmc.Sobol(d=n2, scramble=True, seed=seed)
    if start > 0:  # fast_forward(0) overflows in SciPy 1.17
        engine.fast_forward(start)
    import warnings

    with warnings.catch_warnings():  # a task's rows are a part of the design, not a design of their own
        warnings.filterwarnings("ignore", "The balance properties", UserWarning)
        return engine.random(stop - start)


def _scrambled_sobol(n2: int, m: int, seed) -> np.ndarray:
    from scipy.stats import qmc

    return qmc.Sobol(d=n2, scramble=True, seed=seed).random_base2(m)


@functools.lru_cache(maxsize=16)
def _sobol_points(n2: int, m: int, seed: int) -> np.ndarray:
    """The scrambled Sobol points of a fixed seed, drawn once (read-only)."""
    u = _scrambled_sobol(n2, m, seed)
    u.flags.writeable = False
    return u


# ----------------------------------------------------------------------------- minima
def to_unit(cands: np.ndarray, params) -> np.ndarray:
    """Candidates mapped through their priors' CDFs to [0, 1]^n2."""
    if not params:
        return cands
    return np.column_stack(
        [np.clip(p.sampling_prior.cdf(cands[:, j], p.lb, p.ub), 0.0, 1.0) for j, p in enumerate(params)]
    )


def nearest_neighbours(points: np.ndarray, k: int, block: int = 512, threads: int = 1) -> np.ndarray:
    """Indices of each point's k nearest other points, shape (M, k).

    Blocked NumPy distances up to 1024 points; a k-d tree beyond (the quadratic search costs
    30-300 ms at 2000-4000 points against 3-30 ms, once scipy.spatial is imported, a one-off
    0.2-0.6 s in a process), queried on ``threads`` threads (2050 points in 5 dimensions:
    12.5 ms on one, 7.2 ms on two).
    """
    M = points.shape[0]
    if M > 1024:
        from scipy.spatial import cKDTree

        return cKDTree(points).query(points, k=k + 1, workers=max(1, int(threads)))[1][:, 1:]
    sq = np.einsum("ij,ij->i", points, points)
    out = np.empty((M, k), dtype=np.intp)
    for start in range(0, M, block):
        rows = slice(start, min(start + block, M))
        d2 = sq[rows, None] + sq[None, :] - 2.0 * points[rows] @ points.T
        d2[np.arange(d2.shape[0]), np.arange(start, rows.stop)] = np.inf  # not its own neighbour
        near = np.argpartition(d2, k - 1, axis=1)[:, :k]
        out[rows] = near
    return out


def design_neighbours(unit: np.ndarray, threads: int = 1) -> np.ndarray | None:
    """The ``2 n2 + 2`` nearest other candidates of each one of a scattered design (unordered),
    shape (M, k); None for fewer than two candidates. Computed once per landscape: the local
    minima and the sampling distance of Eq. 17 both read them; and once per design, since every
    sweep of the same settings and dimension draws the same points (a warm call, a Monte-Carlo run)."""
    M, n2 = unit.shape
    if M <= 1:
        return None

    def compute():
        near = nearest_neighbours(unit, min(M - 1, 2 * n2 + 2), threads=threads)
        near.flags.writeable = False  # shared by every landscape of this design
        return near

    return _per_design(unit, "neighbours", compute)


def sampling_distance(unit: np.ndarray, neighbours: np.ndarray | None = None) -> float:
    """The design's median distance from a candidate to its nearest other one, in ``unit``
    coordinates (``neighbours`` as :func:`design_neighbours` gives them, computed when not given)."""
    near = design_neighbours(unit) if neighbours is None else neighbours
    if near is None:
        return 0.0
    return _per_design(unit, "distance", lambda: float(
        np.median(np.linalg.norm(unit[:, None, :] - unit[near], axis=2).min(axis=1))))


def _per_design(unit: np.ndarray, what: str, compute):
    """``compute()`` once per design (its points' digest) among the last few designs."""
    key = (what, unit.shape, hashlib.blake2b(np.ascontiguousarray(unit).tobytes(), digest_size=16).digest())
    with _DESIGNS_LOCK:
        if key in _DESIGNS:
            return _DESIGNS[key]
    value = compute()
    with _DESIGNS_LOCK:
        _DESIGNS[key] = value
        while len(_DESIGNS) > 16:
            _DESIGNS.pop(next(iter(_DESIGNS)))
    return value


#: what was computed of the last designs, by their points' digest
_DESIGNS: dict = {}
_DESIGNS_LOCK = threading.Lock()
register_memory_cache(_DESIGNS.clear)
register_memory_cache(_sobol_points.cache_clear)


def prior_density(params, xi2: np.ndarray) -> np.ndarray:
    """d(prior CDF)/d(xi2) at ``xi2`` by central differences, shape (n2,)."""
    out = []
    for j, p in enumerate(params):
        h = 1e-6 * max(abs(xi2[j]), p.typical_scale)
        lo, hi = max(xi2[j] - h, p.lb), min(xi2[j] + h, p.ub)
        c = p.sampling_prior.cdf(np.array([lo, hi]), p.lb, p.ub)
        out.append((c[1] - c[0]) / (hi - lo) if hi > lo else 0.0)
    return np.array(out, dtype=float)


def local_design(center: np.ndarray, step: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """Points around ``center`` at +-``step``: a 3**n2 grid up to n2 = 4, the 2 n2 axis points above."""
    n2 = len(center)
    if n2 <= 4:
        offsets = np.array(np.meshgrid(*[[-1.0, 0.0, 1.0]] * n2, indexing="ij")).reshape(n2, -1).T
        offsets = offsets[np.any(offsets != 0, axis=1)]
    else:
        offsets = np.vstack([np.eye(n2), -np.eye(n2)])
    pts = np.clip(center[None, :] + offsets * step[None, :], lb, ub)
    return np.unique(pts[np.any(pts != center[None, :], axis=1)], axis=0)


def half_step(cands: np.ndarray, unit: np.ndarray, grid_shape, params, best: int,
              spacing: float | None = None) -> np.ndarray:
    """Half the local sampling distance per xi2 component (the Delta xi2 of Eq. 17); ``spacing``
    of a scattered design as :func:`sampling_distance` gives it (computed when not given)."""
    if grid_shape is not None:
        steps = []
        for j in range(cands.shape[1]):
            axis = np.unique(cands[:, j])
            if axis.size < 2:
                steps.append(0.0)
                continue
            pos = int(np.searchsorted(axis, cands[best, j]))
            gaps = np.diff(axis)[max(pos - 1, 0) : pos + 1]
            steps.append(float(np.max(gaps)))
        return 0.5 * np.array(steps)
    if cands.shape[0] < 2:
        return np.zeros(cands.shape[1])
    du = 0.5 * (sampling_distance(unit) if spacing is None else spacing) / math.sqrt(cands.shape[1])
    steps = []
    for j, p in enumerate(params):
        u = unit[best, j]
        lo, hi = p.sampling_prior.ppf(np.array([max(u - du, 0.0), min(u + du, 1.0)]), p.lb, p.ub)
        steps.append(0.5 * abs(hi - lo))
    return np.array(steps)


def check_sweep_memory(n_candidates: int, partition: Partition, n_outputs: int, fraction: float = 0.5) -> None:
    """Refuse a sweep whose arrays (candidates, their xi1, R and rankings, in float64) would take more
    than ``fraction`` of the memory available now, with the figure and what to do."""
    import os

    per_candidate = 8 * (2 * partition.n_nonlinear + 2 * partition.n_linear + 2 * n_outputs + 4)
    need = float(n_candidates) * per_candidate
    try:
        available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):  # not POSIX: no figure to compare with
        return
    if need > fraction * available:
        raise OptionError(f"a sweep of {n_candidates:g} candidates needs about {need / 2**30:.1f} GiB for its arrays, "
                          f"more than half of the {available / 2**30:.1f} GiB available: use fewer candidates "
                          "(SweepSettings.n_candidates, --candidates), or sweep the range in parts with explicit "
                          "candidates (sweep(..., candidates=...))")
