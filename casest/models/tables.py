"""Lookup tables whose grid casest knows, and the check that data stay on it.

A ``casadi.interpolant`` does not tell its grid: evaluated outside it, a linear table
extrapolates its end segment and a B-spline its end polynomial, silently. A table built with
:func:`lookup_table` is a ``casadi.interpolant`` like any other (it goes into outputs and
right-hand sides as one), and casest records its grid, so that :func:`table_coverage` can say
which samples of a record fall outside it at an estimate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import casadi as ca
import numpy as np

from ..errors import ModelError
from ..status import Note, NoteCode
from ..options import TableMethod

__all__ = ["lookup_table", "TableCoverage", "table_coverage", "coverage_notes"]

#: the tables built by lookup_table with their grids, by the Function's identity (CasADi's hash of
#: its node); the Function is kept so that no later table can reuse the identity
_GRIDS: dict[int, tuple[ca.Function, str, tuple[np.ndarray, ...]]] = {}


def lookup_table(name: str, grid: Sequence, values, method: TableMethod = "linear") -> ca.Function:
    """A ``casadi.interpolant`` whose grid casest records, so that estimates can say when the data
    reach beyond it.

    Parameters
    ----------
    name : str
        The table's name, as notes will give it.
    grid : sequence of array_like
        One increasing vector of breakpoints per dimension.
    values : array_like
        The table's values, in CasADi's order (first dimension fastest), size the product of the
        grid's lengths.
    method : {"linear", "bspline"}

    Returns
    -------
    casadi.Function
        The interpolant: call it on CasADi expressions, one argument per dimension stacked.

    Raises
    ------
    ModelError
        A breakpoint vector that is not increasing or not finite, values of the wrong size or
        not finite, an unknown method.
    """
    if method not in ("linear", "bspline"):
        raise ModelError(f"lookup_table {name!r}: method must be 'linear' or 'bspline', got {method!r}")
    axes = tuple(_breakpoints(name, d, g) for d, g in enumerate(grid))
    flat = np.asarray(values, dtype=float).reshape(-1, order="F")
    if flat.size != int(np.prod([a.size for a in axes])):
        raise ModelError(f"lookup_table {name!r}: {flat.size} values for a grid of {[a.size for a in axes]} "
                         f"points ({int(np.prod([a.size for a in axes]))} values needed)")
    if not np.all(np.isfinite(flat)):
        bad = np.flatnonzero(~np.isfinite(flat))[:5].tolist()
        raise ModelError(f"lookup_table {name!r}: values at flat positions {bad} (CasADi's order, first dimension "
                         "fastest) are not finite: every estimate near them would be NaN; fill the table's gaps")
    table = ca.interpolant(name, method, [a.tolist() for a in axes], flat.tolist())
    _GRIDS[hash(table)] = (table, name, axes)
    return table


def _breakpoints(name: str, dimension: int, values) -> np.ndarray:
    """One dimension's breakpoints: at least two finite, strictly increasing values."""
    axis = np.asarray(values, dtype=float).reshape(-1)
    if axis.size < 2 or not np.all(np.isfinite(axis)) or not np.all(np.diff(axis) > 0):
        raise ModelError(f"lookup_table {name!r}: breakpoints of dimension {dimension} must be at least two finite, "
                         f"strictly increasing values")
    return axis


@dataclass(frozen=True)
class TableCoverage:
    """Where a record takes one dimension of a lookup table at an estimate.

    Attributes
    ----------
    table : str
        The table's name.
    dimension : int
        Which of its arguments (0 for a 1-D table).
    grid : (float, float)
        The first and last breakpoints (``nan`` when casest does not know the grid).
    reached : (float, float)
        The smallest and largest argument over the record.
    outside : int
        Samples whose argument lies outside the grid.
    n_samples : int
    """

    table: str
    dimension: int
    grid: tuple
    reached: tuple
    outside: int
    n_samples: int

    @property
    def known(self) -> bool:
        """Whether casest knows the table's grid (built with :func:`lookup_table`)."""
        return bool(np.isfinite(self.grid[0]))


def _calls(expr: ca.SX) -> list:
    """The call nodes of lookup tables in an SX expression (each shared node once)."""
    found, seen, stack = [], set(), [expr[i] for i in range(expr.numel())]
    while stack:
        node = stack.pop()
        key = node.element_hash()
        if key in seen:
            continue
        seen.add(key)
        if node.is_call():
            found.append(node)
        stack.extend(node.dep(i) for i in range(node.n_dep()))
    return found


def table_coverage(model, data, theta) -> list[TableCoverage]:
    """Each lookup-table argument of a static model over a record, against the table's grid.

    Parameters
    ----------
    model : Model
        A static model (its outputs may call tables).
    data : Dataset
        The record (``data.signals`` in the model's signal order).
    theta : array_like, shape (n_parameters,)
        The estimate, physical units.

    Returns
    -------
    list of TableCoverage
        One per table call and dimension; empty when the outputs call no table.
    """
    calls = _calls(model.h)
    if not calls:
        return []
    X = np.asarray(data.signals, dtype=float)
    out = []
    for node in calls:
        fn = node.which_function()
        _, name, axes = _GRIDS.get(hash(fn), (fn, fn.name(), None))
        arguments = ca.vertcat(*[node.dep(i) for i in range(node.n_dep())])
        values = np.asarray(ca.Function("table_arguments", [model.x, model.theta], [arguments])
                            .map(X.shape[0])(X.T, np.asarray(theta, dtype=float))).reshape(node.n_dep(), -1)
        for d in range(values.shape[0]):
            v = values[d][np.isfinite(values[d])]
            lo, hi = (float(axes[d][0]), float(axes[d][-1])) if axes is not None and d < len(axes) else (np.nan, np.nan)
            outside = int(np.sum((v < lo) | (v > hi))) if np.isfinite(lo) else 0
            out.append(TableCoverage(name, d, (lo, hi), (float(v.min()), float(v.max())) if v.size else (np.nan, np.nan),
                                     outside, int(v.size)))
    return out


def coverage_notes(model, data, theta) -> list[Note]:
    """Notes for the estimate: each table dimension the record takes beyond its grid (how many
    samples, how far), and the tables whose grid casest cannot see (built by ``casadi.interpolant``
    directly). Static models; none for a model without tables.

    Parameters
    ----------
    model : Model
    data : Dataset
    theta : array_like, shape (n_parameters,)

    Returns
    -------
    list of Note
        Code ``NoteCode.TABLE_RANGE``.
    """
    from .static import Model

    if not isinstance(model, Model):
        return []
    coverage = table_coverage(model, data, theta)
    notes = [Note(f"lookup table {c.table!r}" + (f" (argument {c.dimension})" if c.dimension else "")
                  + f" is evaluated outside its grid [{c.grid[0]:g}, {c.grid[1]:g}] at {c.outside} of {c.n_samples} "
                  f"samples (the record reaches [{c.reached[0]:g}, {c.reached[1]:g}]): there it extrapolates its end "
                  "segment, which the table's data do not support; extend the grid or drop those samples",
                  NoteCode.TABLE_RANGE) for c in coverage if c.known and c.outside]
    unknown = sorted({c.table for c in coverage if not c.known})
    if unknown:
        notes.append(Note(f"casest cannot see the grid of lookup table(s) {unknown} (built by casadi.interpolant), so "
                          "it does not check that the record stays on it; build them with casest.lookup_table(name, "
                          "grid, values, method) to have it checked", NoteCode.TABLE_RANGE))
    return notes
