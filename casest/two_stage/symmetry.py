"""Symmetries of a model's parameters, and the canonical labels of an estimate.

A *symmetry* is a map of the parameters that leaves every output unchanged, so that the data
cannot tell ``theta`` from its image: exchanging two terms of a sum (``a0, b0 <-> a1, b1`` in
``a0 exp(-b0 x) + a1 exp(-b1 x)``), or flipping signs and shifting by pi (``a sin(w x + phi)``
with ``a -> -a, phi -> phi + pi``). Each is found by testing candidate maps on the model itself
(:func:`model_symmetries`): exchanges of two parameters with the same unit and prior whose boxes
overlap (an exchange then maps each value into the other's box where the estimate lies in both;
the labelling keeps only images inside the bounds), sign flips of one or two parameters, with or
without a shift by +-pi of one, and products of up to four exchanges.
A candidate is a symmetry when the outputs at the estimate and at two points near it, on the
data's signals, agree to 1e-9 (relative) with those at the images, and every parameter it
moves acts on the outputs there.

An estimate of a symmetric model is then labelled canonically (:func:`canonical_labels`).
The rule: among the images of the estimate inside the bounds, the one with the fewest negative
values among the parameters a symmetry flips (a sign alias comes out positive: the amplitude of
``a sin(w x + phi)`` positive, the phase shifted by pi to match), then the fewest negative
parameters in all, then the one whose scaled parameters are smallest in lexicographic order,
the boxed parameters first (exchangeable terms then come out with ascending rates or centres).
Every start, run and machine returns the same labels, and the note names the symmetry.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np

from .._casadi.memory import StructureCache
from .._casadi.sample_blocks import evaluate_samples
from ..status import Note, NoteCode

__all__ = ["ParameterMap", "model_symmetries", "canonical_labels", "related", "in_labels_of", "labelled_estimate",
           "merging_terms", "exchanged_pairs", "MERGE_RTOL", "CANCEL_SHARE"]

#: two exchangeable terms merge when each of their exchanged nonlinear parameters differ by at most
#: this share of the larger ...
MERGE_RTOL = 0.01
#: ... and their exchanged linear parameters (amplitudes) have opposite signs and cancel to this share
CANCEL_SHARE = 0.1

#: at most this many candidate maps are tested per model (the search is for small symmetry groups)
MAX_CANDIDATES = 3000
_CACHE = StructureCache()


@dataclass(frozen=True)
class ParameterMap:
    """``theta -> theta[order] * signs + shifts``: a candidate symmetry of the parameters.

    Attributes
    ----------
    order : tuple of int
    signs : tuple of float
    shifts : tuple of float
    description : str
        For example ``"'a0' <-> 'a1', 'b0' <-> 'b1'"`` or ``"'a' -> -'a', 'phi' -> 'phi' + pi"``.
    """

    order: tuple
    signs: tuple
    shifts: tuple
    description: str

    def apply(self, theta: np.ndarray) -> np.ndarray:
        """The image of ``theta``, shape (n_parameters,)."""
        return np.asarray(theta, dtype=float)[list(self.order)] * np.asarray(self.signs) + np.asarray(self.shifts)


def _compatible(p, q) -> bool:
    """Whether two parameters may be exchanged: the same unit and prior, and boxes that overlap
    (otherwise no value of one can take the other's place)."""
    overlap = max(p.lb, q.lb) <= min(p.ub, q.ub)
    return overlap and p.unit == q.unit and type(p.declared_prior) is type(q.declared_prior)


def _candidates(model):
    """Single exchanges, then sign flips with optional pi shifts, then products of two to four
    disjoint exchanges (the budget reaches the simple maps first)."""
    n, names = model.n_parameters, model.parameter_names
    pairs = [(i, j) for i, j in itertools.combinations(range(n), 2) if _compatible(model.parameters[i], model.parameters[j])]
    count = 0
    for candidate in itertools.chain(_exchanges(n, names, pairs, (1,)), _sign_flips(n, names),
                                     _exchanges(n, names, pairs, range(2, min(4, len(pairs)) + 1))):
        count += 1
        if count > MAX_CANDIDATES:
            return
        yield candidate


def _exchanges(n: int, names, pairs: list, sizes):
    """Products of ``size`` disjoint transpositions of ``pairs``, for each size."""
    identity = tuple(range(n))
    for size in sizes:
        for chosen in itertools.combinations(pairs, size):
            used = [k for pair in chosen for k in pair]
            if len(set(used)) != len(used):
                continue
            order = list(identity)
            for i, j in chosen:
                order[i], order[j] = j, i
            yield ParameterMap(tuple(order), (1.0,) * n, (0.0,) * n,
                               ", ".join(f"{names[i]!r} <-> {names[j]!r}" for i, j in chosen))


def _sign_flips(n: int, names):
    """Sign flips of one or two parameters, with or without a shift by +-pi of another."""
    identity = tuple(range(n))
    for size in (1, 2):
        for flipped in itertools.combinations(range(n), size):
            signs = tuple(-1.0 if k in flipped else 1.0 for k in range(n))
            for shifted, shift in [(None, 0.0)] + [(k, s) for k in range(n) if k not in flipped for s in (np.pi, -np.pi)]:
                shifts = tuple(shift if k == shifted else 0.0 for k in range(n))
                words = [f"{names[k]!r} -> -{names[k]!r}" for k in flipped]
                if shifted is not None:
                    words.append(f"{names[shifted]!r} -> {names[shifted]!r} {'+' if shift > 0 else '-'} pi")
                yield ParameterMap(identity, signs, shifts, ", ".join(words))


def _predict_many(model, thetas: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """h at every row for every parameter vector, shape (K, R, n_outputs), in one CasADi call."""
    K, R = thetas.shape[0], rows.shape[0]
    # sample k R + r: the rows' r-th signals at the k-th theta
    (values,) = evaluate_samples(model.function, [np.tile(rows, (K, 1)), np.repeat(thetas, R, axis=0)])
    return values.reshape(K, R, model.n_outputs)


def _candidate_list(model, signals: np.ndarray | None = None) -> list:
    """The candidate maps that hold at a generic point of the box (once per model structure).

    A symmetry is an identity of the model, so it holds at any point where its parameters act;
    a candidate that fails at a generic point is no symmetry anywhere. (One that holds there may
    still be refuted near an estimate: :func:`model_symmetries` tests the survivors again.)
    """
    cached = _CACHE.setdefault(model, {})
    if "candidates" not in cached:
        candidates = list(_candidates(model))
        if signals is not None and candidates:
            rng = np.random.default_rng(1)
            generic = np.clip(model.nominal + 0.3 * model.scales * rng.standard_normal(model.n_parameters),
                              model.lower_bounds, model.upper_bounds)
            candidates = _screened(model, candidates, generic, np.asarray(signals, dtype=float), keep_fixed=True)
        cached["candidates"] = candidates
    return cached["candidates"]


def model_symmetries(model, signals: np.ndarray, theta: np.ndarray | None = None) -> tuple:
    """The maps of the parameters that leave the outputs of a static model unchanged near
    ``theta`` (module docstring).

    A candidate is tested at ``theta`` (default: the nominal values) and at two points 5 % of
    the parameters' scales from it (of their magnitudes where those are smaller), on up to 64 of the data's signal rows; every parameter it
    moves must act on the outputs there (a term that vanishes at the rows would pass any test).
    Dynamic models are not searched.

    Parameters
    ----------
    model : Model
    signals : ndarray, shape (N, n_signals)
    theta : ndarray, shape (n_parameters,), optional

    Returns
    -------
    tuple of ParameterMap
    """
    if hasattr(model, "states"):
        return ()
    candidates = _candidate_list(model, signals)
    if not candidates:
        return ()
    centre = np.asarray(model.nominal if theta is None else theta, dtype=float)
    candidates = _screened(model, candidates, centre, np.asarray(signals, dtype=float))
    if not candidates:
        return ()
    rng = np.random.default_rng(0)
    # near the estimate: a box's scale (a centre's box up to 1e5, say) can move a term off the data
    scales = np.where(np.abs(centre) > 0, np.minimum(model.scales, np.abs(centre)), model.scales)
    points = [centre] + [np.clip(centre + 0.05 * scales * rng.standard_normal(centre.size),
                                 model.lower_bounds, model.upper_bounds) for _ in range(2)]
    rows = np.asarray(signals, dtype=float)
    rows = rows[np.linspace(0, len(rows) - 1, min(64, len(rows))).astype(int)]
    n = model.n_parameters
    steps = [p + np.diag(1e-3 * scales) for p in points]  # one parameter moved at a time
    images = [c.apply(p) for p in points for c in candidates]
    with np.errstate(all="ignore"):
        values = _predict_many(model, np.vstack([np.array(points)] + steps + [np.array(images)]), rows)
    base, moved = values[:3], values[3:3 + 3 * n].reshape(3, n, *values.shape[1:])
    mapped = values[3 + 3 * n:].reshape(3, len(candidates), *values.shape[1:])
    size = np.maximum(np.max(np.abs(base), axis=(1, 2)), 1e-300)
    active = np.max(np.abs(moved - base[:, None]), axis=(2, 3)) > 1e-7 * size[:, None]  # (3, n)
    if not np.all(np.isfinite(base)):
        return ()
    found = []
    for c, candidate in enumerate(candidates):
        changed = [k for k in range(n) if candidate.order[k] != k or candidate.signs[k] != 1.0 or candidate.shifts[k] != 0.0]
        if not active[:, changed].all():
            continue  # a parameter that does not act at a test point would pass any test there
        if all(np.allclose(mapped[p, c], base[p], rtol=1e-9, atol=1e-12 * size[p]) for p in range(3)):
            found.append(candidate)
    return tuple(found)


def _screened(model, candidates: list, centre: np.ndarray, signals: np.ndarray, keep_fixed: bool = False) -> list:
    """The candidates whose image of ``centre`` fits 8 of the rows as ``centre`` does (a cheap first test).

    A map that leaves ``centre`` itself in place (a sign flip of a zero) says nothing there: it is
    dropped, or kept untested with ``keep_fixed``."""
    rows = signals[np.linspace(0, len(signals) - 1, min(8, len(signals))).astype(int)]
    tolerance = 1e-9 * np.maximum(model.scales, np.abs(centre))
    images = _images(candidates, centre)
    moving = np.any(np.abs(images - centre) > tolerance, axis=1)
    fixed = [c for c, m in zip(candidates, moving) if not m] if keep_fixed else []
    candidates, images = [c for c, m in zip(candidates, moving) if m], images[moving]
    if not candidates:
        return fixed
    with np.errstate(all="ignore"):
        values = _predict_many(model, np.vstack([centre[None, :], images]), rows)
    base = values[0]
    if not np.all(np.isfinite(base)):
        return fixed + candidates  # nothing can be refuted at a point where the model is not finite
    atol = 1e-12 * max(float(np.max(np.abs(base))), 1e-300)
    # np.allclose(v, base, rtol=1e-9, atol=atol) of every candidate at once
    with np.errstate(invalid="ignore"):
        close = np.all(np.abs(values[1:] - base) <= atol + 1e-9 * np.abs(base), axis=(1, 2))
    return fixed + [c for c, ok in zip(candidates, close) if ok]


def _images(candidates: list, theta: np.ndarray) -> np.ndarray:
    """Every candidate's image of ``theta``, shape (n_candidates, n_parameters)."""
    order = np.array([c.order for c in candidates], dtype=int).reshape(len(candidates), -1)
    signs = np.array([c.signs for c in candidates], dtype=float).reshape(order.shape)
    shifts = np.array([c.shifts for c in candidates], dtype=float).reshape(order.shape)
    return np.asarray(theta, dtype=float)[order] * signs + shifts


def _orbit(theta: np.ndarray, maps: tuple, depth: int = 3) -> list:
    seen, frontier = [np.asarray(theta, dtype=float)], [np.asarray(theta, dtype=float)]
    for _ in range(depth):
        nxt = []
        for point in frontier:
            for m in maps:
                image = m.apply(point)
                if not any(np.allclose(image, s, rtol=1e-12, atol=1e-15) for s in seen):
                    seen.append(image)
                    nxt.append(image)
        frontier = nxt
    return seen


def canonical_labels(model, theta: np.ndarray, maps: tuple) -> tuple:
    """The canonical image of ``theta`` under the symmetries ``maps``, inside the bounds.

    Parameters
    ----------
    model : Model
    theta : ndarray, shape (n_parameters,)
    maps : tuple of ParameterMap

    Returns
    -------
    theta : ndarray, shape (n_parameters,)
        The image with the fewest negative values among the parameters a map flips (a sign
        alias comes out positive, a phase shifted to match), then the fewest negative
        parameters, then the one whose scaled parameters are lexicographically smallest, the
        parameters with a finite box first (so that exchangeable terms come out with their rates
        or centres in ascending order), each group in declared order; ``theta`` itself when no
        image lies inside the bounds. An image must hold as many parameters on their lower and
        upper bounds as ``theta`` does: exchanging a parameter held by its bound with one whose
        box does not hold it there gives a point that is not a minimum of the box problem.
    changed : bool
        Whether the labels changed.
    """
    if not maps:
        return np.asarray(theta, dtype=float), False
    span = np.where(np.isfinite(model.upper_bounds - model.lower_bounds), model.upper_bounds - model.lower_bounds, 1.0)
    slack = 1e-9 * np.maximum(span, 1.0)
    held = _bounds_held(model, theta)
    # an image that moves a value held by a bound onto a parameter whose box does not hold it is another
    # point of the box problem, not an equivalent minimum (exchanged parameters with different boxes)
    inside = [p for p in _orbit(theta, maps)
              if np.all(p >= model.lower_bounds - slack) and np.all(p <= model.upper_bounds + slack)
              and _bounds_held(model, p) == held]
    # the boxed parameters (rates, centres, frequencies: xi2 as a rule) first, in declared order
    order = sorted(range(model.n_parameters), key=lambda k: not (np.isfinite(model.lower_bounds[k])
                                                              and np.isfinite(model.upper_bounds[k])))
    # the flipped parameters positive first (amplitudes, widths, frequencies a sign flip aliases),
    # whatever the sign of a phase shifted with them
    flipped = np.array([any(m.signs[k] < 0 for m in maps) for k in range(model.n_parameters)])
    best = min(inside, key=lambda p: (int(np.sum(p[flipped] < 0)), int(np.sum(p < 0)),
                                      tuple(np.round(p[order] / model.scales[order], 9))))
    return np.clip(best, model.lower_bounds, model.upper_bounds), not np.allclose(best, theta, rtol=1e-12, atol=0)


def _bounds_held(model, theta: np.ndarray) -> tuple:
    """How many parameters of ``theta`` lie on a lower and on an upper bound (``active_bounds``' rule)."""
    from ..backend.ipopt import active_bounds

    sides = active_bounds(theta, model.lower_bounds, model.upper_bounds, model.scales)
    return sides.count("lower"), sides.count("upper")


def related(model, theta: np.ndarray, other: np.ndarray, maps: tuple) -> bool:
    """Whether ``other`` is an image of ``theta`` under the symmetries ``maps`` (compositions of
    up to three), to 1e-4 of each parameter's magnitude or scale.

    Parameters
    ----------
    model : Model
    theta, other : ndarray, shape (n_parameters,)
    maps : tuple of ParameterMap

    Returns
    -------
    bool
    """
    if not maps:
        return False
    tolerance = 1e-4 * np.maximum(model.scales, np.abs(other))
    return any(np.all(np.abs(image - other) <= tolerance) for image in _orbit(theta, maps)[1:])


def in_labels_of(model, signals: np.ndarray, theta: np.ndarray, std: np.ndarray, reference: np.ndarray) -> tuple:
    """An estimate in another labelling (a published one, say): of the model's symmetries at
    ``theta`` and the identity, the image nearest ``reference`` (smallest largest relative
    difference), with the std moved alike.

    casest labels a symmetric model canonically (:func:`canonical_labels`); a reference may label
    the same point otherwise (NIST's ENSO lists its two cycles in another order).

    Parameters
    ----------
    model : Model
    signals : ndarray, shape (N, n_signals)
        The data's signals (where the symmetries are tested).
    theta, std : ndarray, shape (n_parameters,)
    reference : ndarray, shape (n_parameters,)

    Returns
    -------
    theta, std : ndarray, shape (n_parameters,)
    """
    theta, std, reference = (np.asarray(v, dtype=float) for v in (theta, std, reference))

    def distance(image):
        return float(np.max(np.abs(image - reference) / np.maximum(np.abs(reference), 1e-300)))

    maps = model_symmetries(model, signals, theta)
    best = min([None, *maps], key=lambda m: distance(theta if m is None else m.apply(theta)))
    if best is None:
        return theta, std
    return best.apply(theta), std[list(best.order)]


def exchanged_pairs(m: ParameterMap, linear) -> tuple:
    """The pairs a pure exchange of terms swaps: its nonlinear and its linear parameters.

    Parameters
    ----------
    m : ParameterMap
    linear : set of int
        The linear parameters (amplitudes).

    Returns
    -------
    rates, amplitudes : list of (int, int)
        (lower, higher) index pairs; both empty for a map that flips a sign or shifts.
    """
    if any(s != 1.0 for s in m.signs) or any(h != 0.0 for h in m.shifts):
        return [], []
    pairs = [(k, int(j)) for k, j in enumerate(m.order) if j > k]
    return [(k, j) for k, j in pairs if k not in linear], [(k, j) for k, j in pairs if k in linear]


def merging_terms(model, theta: np.ndarray, maps: tuple, linear_index) -> list:
    """The exchanges of terms that merge at ``theta``: their nonlinear parameters nearly equal
    (:data:`MERGE_RTOL`) and their amplitudes of opposite sign, cancelling (:data:`CANCEL_SHARE`).
    Along such a path the cost falls towards a limit no point of the box attains (the difference
    of two equal terms, scaled up, is a derivative term): the estimate is where a solver stopped.

    Parameters
    ----------
    model : Model
    theta : ndarray, shape (n_parameters,)
    maps : tuple of ParameterMap
        The model's symmetries at ``theta`` (:func:`model_symmetries`).
    linear_index : sequence of int
        The linear parameters (amplitudes).

    Returns
    -------
    list of str
        One phrase per merging exchange, naming the values.
    """
    linear, names, out = set(int(i) for i in linear_index), model.parameter_names, []
    for m in maps:
        rates, amplitudes = exchanged_pairs(m, linear)
        if not amplitudes or not rates:
            continue
        close = all(abs(theta[k] - theta[j]) <= MERGE_RTOL * max(abs(theta[k]), abs(theta[j]), 1e-300) for k, j in rates)
        cancel = all(theta[k] * theta[j] < 0 and abs(theta[k] + theta[j]) <= CANCEL_SHARE * max(abs(theta[k]), abs(theta[j]))
                     for k, j in amplitudes)
        if close and cancel:
            out.append(", ".join(f"{names[k]} = {theta[k]:.6g} and {names[j]} = {theta[j]:.6g}" for k, j in rates + amplitudes))
    return out


def labelled_estimate(problem, stage2, linear_index) -> tuple:
    """The stage-2 result labelled canonically under the model's symmetries, with its notes: the
    symmetry (``LABELS``) when an image lies inside the bounds, and terms that merge (``MERGING``).

    Parameters
    ----------
    problem : Problem
    stage2 : Stage2Result
    linear_index : sequence of int
        The linear parameters (:func:`merging_terms`).

    Returns
    -------
    Stage2Result
    list of Note
    """
    if problem.dynamic:
        return stage2, []
    model = problem.model
    maps = model_symmetries(model, problem.data.signals, stage2.theta)
    theta, changed = canonical_labels(model, stage2.theta, maps)
    notes = []
    images = [m for m in maps if not np.allclose(m.apply(theta), theta, rtol=1e-9, atol=0)
              and np.all(m.apply(theta) >= model.lower_bounds) and np.all(m.apply(theta) <= model.upper_bounds)]
    if images:
        notes.append(Note(f"the model has a symmetry or alias ({'; '.join(m.description for m in images)}): each image "
                          "of the estimate fits the data equally, so its labels are a convention; casest returns the "
                          "image with the fewest negative parameters, then the smallest boxed ones in declared order "
                          "(exchangeable terms by ascending rate or centre)"
                          + (", relabelled from the solver's solution" if changed else ""), NoteCode.LABELS))
        stage2 = replace(stage2, theta=theta) if changed else stage2
    for merging in merging_terms(model, stage2.theta, maps, linear_index):
        notes.append(Note(f"two terms merge ({merging}): their nonlinear parameters are nearly equal and their amplitudes "
                          "cancel, so the cost falls as they merge towards a limit that no point of the box attains (the "
                          "difference of two equal terms, scaled up, is a derivative term); the estimate is where the "
                          "solver stopped, not a minimum. Fit a model with one term fewer, or with the derivative term "
                          "(x exp(-b x) for exponentials)", NoteCode.MERGING))
    return stage2, notes
