"""Automatic separation of the parameters into xi1 (enter affinely) and xi2 (the rest).

A set S of parameters enters h *jointly affinely* when every second derivative
d2h / (d theta_i d theta_j), i, j in S, is structurally zero. Then
``h = A(x, xi2) xi1 + b(x, xi2)`` (paper Eq. 4) with ``A = dh/dxi1`` and
``b = h(xi1 = 0)``. The separator picks the largest such set, so that the part that
stage 1 must sweep (xi2) is as small as possible.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import casadi as ca
import numpy as np

from .._casadi.memory import BuildCache, StructureCache
from ..errors import SeparationError
from ..models import Model
from .measurement import Measurement, as_measurement


__all__ = ["Partition", "separate", "interaction_graph", "SeparationError"]



def interaction_graph(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """Structural second-derivative pattern of the outputs in the parameters.

    ``dh/dtheta_i`` is differentiated symbolically and tested with
    ``casadi.depends_on``; this is stricter than a numeric Hessian because functions
    such as ``fabs`` or ``sign`` (whose second derivative is zero almost everywhere)
    still count as nonlinear.

    Parameters
    ----------
    model : Model

    Returns
    -------
    self_nonlinear : ndarray of bool, shape (n_parameters,)
        ``True`` where some output is nonlinear in that parameter alone.
    coupled : ndarray of bool, shape (n_parameters, n_parameters)
        Symmetric; ``True`` where the mixed second derivative is structurally non-zero.
    """
    n = model.n_parameters
    jac = output_jacobian(model.h, model.theta)  # n_outputs x n
    self_nonlinear = np.zeros(n, dtype=bool)
    coupled = np.zeros((n, n), dtype=bool)
    for i in range(n):
        column = jac[:, i]
        for j in range(n):
            if ca.depends_on(column, model.theta[j]):
                if i == j:
                    self_nonlinear[i] = True
                else:
                    coupled[i, j] = coupled[j, i] = True
    return self_nonlinear, coupled


def output_jacobian(h, v):
    """``dh/dv`` built one output at a time (shape (n_outputs, n_v)).

    The Jacobian of several outputs at once is built by forward sweeps whose seeds are zero in
    the other directions; a lookup table's derivative calls keep those zero seeds multiplied by
    the parameters, so a parameter that enters linearly through a table looked nonlinear (with
    two or more outputs). One output at a time, each derivative is a single reverse sweep whose
    seeds are the output's own factors.
    """
    if h.numel() <= 1:
        return ca.jacobian(h, v)
    return ca.vertcat(*[ca.jacobian(h[r], v) for r in range(h.numel())])


def _maximum_independent_sets(candidates: list[int], coupled: np.ndarray) -> list[frozenset]:
    """All maximum independent sets of the graph ``coupled`` restricted to ``candidates``.

    Bron-Kerbosch with pivoting on the complement graph (an independent set of G is a
    clique of its complement). Exact; fine for the tens of parameters of calibration
    problems.
    """
    cand = set(candidates)
    neighbours = {v: {w for w in cand if w != v and not coupled[v, w]} for v in cand}
    best: list[frozenset] = []
    best_size = 0

    def expand(r: set, p: set, x: set) -> None:
        nonlocal best, best_size
        if len(r) + len(p) < best_size:
            return
        if not p and not x:
            if len(r) > best_size:
                best, best_size = [frozenset(r)], len(r)
            elif len(r) == best_size:
                best.append(frozenset(r))
            return
        pivot = max(p | x, key=lambda u: len(neighbours[u] & p))
        for v in sorted(p - neighbours[pivot]):
            expand(r | {v}, p & neighbours[v], x & neighbours[v])
            p = p - {v}
            x = x | {v}

    if cand:
        expand(set(), set(cand), set())
    else:
        best = [frozenset()]
    return best


@dataclass(frozen=True)
class Partition:
    """The split xi = [xi1, xi2] and the affine form ``h = A(x, xi2) xi1 + b(x, xi2)``.

    Attributes
    ----------
    linear : tuple of str
        Names in xi1 (model order).
    nonlinear : tuple of str
        Names in xi2 (model order).
    linear_index, nonlinear_index : tuple of int
        Their positions in the model's parameter vector.
    alternatives : tuple of tuple of str
        Other sets of xi1 of the same (maximum) size, if any (ties).
    A : casadi.Function
        ``A(signals[n_signals], xi2[n2]) -> [n_outputs x n1]``.
    b : casadi.Function
        ``b(signals[n_signals], xi2[n2]) -> [n_outputs]``.
    pinned_linear, pinned_nonlinear : tuple of str
        What the user pinned.
    builds : BuildCache
        What the sweep builds from A and b alone (per-sample functions, array programs), kept
        for the next sweep on this split.
    """

    linear: tuple[str, ...]
    nonlinear: tuple[str, ...]
    linear_index: tuple[int, ...]
    nonlinear_index: tuple[int, ...]
    alternatives: tuple[tuple[str, ...], ...]
    A: ca.Function = field(repr=False, compare=False)
    b: ca.Function = field(repr=False, compare=False)
    pinned_linear: tuple[str, ...] = ()
    pinned_nonlinear: tuple[str, ...] = ()
    builds: BuildCache = field(default_factory=BuildCache, repr=False, compare=False)

    @property
    def n_linear(self) -> int:
        return len(self.linear)

    @property
    def n_nonlinear(self) -> int:
        return len(self.nonlinear)

    def describe(self) -> str:
        """One line, e.g. ``xi1 = [a, c] (linear), xi2 = [b] (swept)``.

        Returns
        -------
        str
        """
        text = f"xi1 = [{', '.join(self.linear)}] (linear), xi2 = [{', '.join(self.nonlinear)}] (swept)"
        if self.alternatives:
            alts = "; ".join("[" + ", ".join(a) + "]" for a in self.alternatives)
            text += f"; equally large alternatives for xi1: {alts}"
        return text

    def assemble_symbolic(self, xi1, xi2):
        """theta as a CasADi expression (column) from its xi1 and xi2 parts (expressions).

        Parameters
        ----------
        xi1 : casadi.SX or casadi.MX, shape (n1, 1)
        xi2 : casadi.SX or casadi.MX, shape (n2, 1)

        Returns
        -------
        casadi.SX or casadi.MX, shape (n_parameters, 1)
        """
        parts = [None] * (self.n_linear + self.n_nonlinear)
        for k, i in enumerate(self.linear_index):
            parts[i] = xi1[k]
        for k, i in enumerate(self.nonlinear_index):
            parts[i] = xi2[k]
        return ca.vertcat(*parts)

    def assemble(self, xi1: np.ndarray, xi2: np.ndarray) -> np.ndarray:
        """Full parameter vector from its two parts (model order).

        Parameters
        ----------
        xi1 : ndarray, shape (n1,)
        xi2 : ndarray, shape (n2,)

        Returns
        -------
        ndarray, shape (n_parameters,)
        """
        n = len(self.linear_index) + len(self.nonlinear_index)
        theta = np.empty(n)
        theta[list(self.linear_index)] = np.asarray(xi1, dtype=float).reshape(-1)
        theta[list(self.nonlinear_index)] = np.asarray(xi2, dtype=float).reshape(-1)
        return theta


def separate(
    model: Model | Measurement,
    linear: Sequence[str] = (),
    nonlinear: Sequence[str] = (),
    check_points: int = 8,
    seed: int = 0,
) -> Partition:
    """Find the largest set of parameters that enter the model jointly affinely.

    Parameters
    ----------
    model : Model, DynamicModel or Measurement
        For a :class:`casest.DynamicModel` the split is of its output equation, with the
        parameters of the rhs and of the initial state in xi2 (A and b are then functions
        of the states and inputs). A Problem's ``problem.measurement`` is handed down as it is.
    linear : sequence of str
        Parameters the user pins into xi1. Each must be affine, and affine jointly with
        the other pinned ones.
    nonlinear : sequence of str
        Parameters the user pins into xi2 (swept in stage 1 even if affine).
    check_points : int
        Number of random points at which ``A xi1 + b`` is compared with ``h``.
    seed : int
        Seed of those random points.

    Returns
    -------
    Partition
        Ties are broken by model order (the set with the earliest parameters wins) and
        the other maximal sets are listed in ``alternatives``.

    Raises
    ------
    SeparationError
        A pinned-linear parameter is nonlinear, two pinned-linear parameters multiply
        each other, a name is pinned to both sides, or a name is unknown.
    """
    linear = list(dict.fromkeys(linear))
    nonlinear = list(dict.fromkeys(nonlinear))
    measurement = as_measurement(model)
    # xi1: affine in the outputs jointly, and in neither the rhs nor the initial state of a dynamic model
    through_states = [n for n in linear if n in measurement.through_states]
    if through_states:
        raise SeparationError(f"parameter(s) {through_states} enter the rhs or the initial state of the dynamic "
                              "model, so they act on the outputs through the states and cannot be linear (xi1)")
    nonlinear = nonlinear + [n for n in measurement.through_states if n not in nonlinear]
    output_model = measurement.output_model
    # a model's partition never changes: separate once (the check evaluates A and b)
    key = (tuple(linear), tuple(nonlinear), check_points, seed)
    cached = _PARTITIONS.setdefault(output_model, {})
    if key not in cached:
        cached[key] = _separate(output_model, linear, nonlinear, check_points, seed)
    return cached[key]


_PARTITIONS = StructureCache()


def _separate(model: Model, linear: list, nonlinear: list, check_points: int, seed: int) -> Partition:
    names = model.parameter_names
    self_nonlinear, coupled = interaction_graph(model)
    pin_lin = _checked_pins(model, linear, nonlinear, self_nonlinear, coupled)
    pin_non = model.index(nonlinear) if nonlinear else []
    excluded = set(pin_non) | {i for i in range(len(names)) if self_nonlinear[i]}
    for i in pin_lin:
        excluded |= {j for j in range(len(names)) if coupled[i, j]}
    free = [i for i in range(len(names)) if i not in excluded and i not in pin_lin]
    sets = _maximum_independent_sets(free, coupled)
    sets = sorted((tuple(sorted(set(s) | set(pin_lin))) for s in sets))
    lin_idx = tuple(sets[0])
    non_idx = tuple(i for i in range(len(names)) if i not in lin_idx)
    A, b = _affine_parts(model, lin_idx, non_idx)
    partition = Partition(
        linear=tuple(names[i] for i in lin_idx),
        nonlinear=tuple(names[i] for i in non_idx),
        linear_index=lin_idx,
        nonlinear_index=non_idx,
        alternatives=tuple(tuple(names[i] for i in s) for s in sets[1:]),
        A=A,
        b=b,
        pinned_linear=tuple(linear),
        pinned_nonlinear=tuple(nonlinear),
    )
    _check_affine_form(model, partition, check_points, seed)
    return partition


def _checked_pins(model: Model, linear: list, nonlinear: list, self_nonlinear, coupled) -> list:
    """The indices pinned to xi1, refused when a pin is on both sides, the model is nonlinear in
    it, or two of them are coupled nonlinearly."""
    names = model.parameter_names
    pin_lin = model.index(linear) if linear else []
    both = sorted(set(linear) & set(nonlinear))
    if both:
        raise SeparationError(f"parameter(s) {both} are pinned both to xi1 and to xi2; pick one side")
    for i in pin_lin:
        if self_nonlinear[i]:
            raise SeparationError(
                f"parameter {names[i]!r} is pinned to xi1 but the model is nonlinear in it; "
                "unpin it or rewrite the model"
            )
    for i in pin_lin:
        for j in pin_lin:
            if i < j and coupled[i, j]:
                raise SeparationError(
                    f"parameters {names[i]!r} and {names[j]!r} are both pinned to xi1 but the "
                    "model couples them nonlinearly (e.g. a product); pin only one of them"
                )
    return pin_lin


def _affine_parts(model: Model, lin_idx: tuple, non_idx: tuple) -> tuple[ca.Function, ca.Function]:
    """A(x, xi2) = dh/dxi1 and b(x, xi2) = h at xi1 = 0 (paper Eq. 4)."""
    xi1 = ca.vertcat(*[model.theta[i] for i in lin_idx]) if lin_idx else ca.SX(0, 1)
    xi2 = ca.vertcat(*[model.theta[i] for i in non_idx]) if non_idx else ca.SX(0, 1)
    A_expr = _linear_slope(model, xi1) if lin_idx else ca.SX(model.n_outputs, 0)
    b_expr = ca.substitute(model.h, xi1, ca.DM.zeros(len(lin_idx))) if lin_idx else model.h
    A = ca.Function("A", [model.x, xi2], [ca.densify(A_expr)], ["signals", "xi2"], ["A"])
    b = ca.Function("b", [model.x, xi2], [ca.densify(b_expr)], ["signals", "xi2"], ["b"])
    return A, b


def _linear_slope(model: Model, xi1: ca.SX) -> ca.SX:
    """dh/dxi1, which does not depend on xi1 (h is jointly affine in it)."""
    A_expr = output_jacobian(model.h, xi1)
    if ca.depends_on(A_expr, xi1):
        # a lookup table's derivative calls keep xi1 as factors of zero seeds: A is constant in xi1
        # (h is affine in it), so A at xi1 = 0 is exact; _check_affine_form verifies it numerically
        A_expr = ca.substitute(A_expr, xi1, ca.DM.zeros(xi1.numel()))
    if ca.depends_on(A_expr, xi1):
        raise RuntimeError("A depends on xi1 although the separator found xi1 jointly affine; please report this model")
    return A_expr


def _check_affine_form(model: Model, partition: Partition, n_points: int, seed: int) -> None:
    """Compare A xi1 + b with h at random points (finite ones only)."""
    rng = np.random.default_rng(seed)
    n_checked = 0
    for _ in range(max(4 * n_points, 1)):
        if n_checked >= n_points:
            break
        signals = rng.uniform(0.3, 1.7, model.n_signals) * rng.choice([-1.0, 1.0], model.n_signals)
        theta = model.nominal + model.scales * rng.uniform(-0.5, 0.5, model.n_parameters)
        theta = np.clip(theta, model.lower_bounds, model.upper_bounds)
        xi1 = theta[list(partition.linear_index)]
        xi2 = theta[list(partition.nonlinear_index)]
        h = np.array(model.function(signals, theta)).reshape(-1)
        A = np.array(partition.A(signals, xi2)).reshape(model.n_outputs, -1)
        b = np.array(partition.b(signals, xi2)).reshape(-1)
        if not (np.all(np.isfinite(h)) and np.all(np.isfinite(A)) and np.all(np.isfinite(b))):
            continue
        n_checked += 1
        recon = A @ xi1 + b
        tol = 1e-9 * (1.0 + np.abs(h) + np.abs(A) @ np.abs(xi1) + np.abs(b))
        if np.any(np.abs(recon - h) > tol):
            raise SeparationError(
                "internal error: A xi1 + b does not reproduce h at a random point "
                f"(max difference {np.max(np.abs(recon - h)):.3g}); please report this model"
            )
