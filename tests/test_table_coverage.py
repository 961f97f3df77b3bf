"""Lookup tables whose grid casest knows (casest.lookup_table): an estimate notes the samples a
record takes beyond the grid; a raw casadi.interpolant is named as unchecked.

Truth: a lift curve tabulated on [-0.5, 0.5] (41 points), data simulated from the model at stated
parameter values with white noise (fixed seeds); the expected count of samples beyond the grid is
computed from the estimate by hand (alpha + b_hat > 0.5).
"""

import casadi as ca
import numpy as np
import pytest

import casest
from casest.errors import ModelError
from casest.status import NoteCode

P = casest.Parameter
GRID = np.linspace(-0.5, 0.5, 41)
LIFT = 2 * np.pi * GRID / (1 + 4 * GRID**2)


def _fit(table, upper: float, seed: int = 0):
    alpha, k, b, c = (ca.SX.sym(n) for n in ("alpha", "k", "b", "c"))
    model = casest.Model([P("k", 0.5, 2.0, 1.0), P("b", -0.1, 0.1, 0.0), P("c", nominal=0.0)], ["alpha"],
                         {"CLm": k * table(alpha + b) + c})
    rng = np.random.default_rng(seed)
    a = rng.uniform(-0.4, upper, 500)
    truth = model.vector({"k": 1.2, "b": 0.03, "c": -0.05})
    z = model.predict(truth, a[:, None])[:, 0] + 0.01 * rng.standard_normal(a.size)
    data = casest.Dataset.from_arrays(model, a[:, None], z[:, None])
    return model, data, casest.estimate(model, data), a


@pytest.mark.parametrize("method", ["linear", "bspline"])
def test_samples_beyond_a_known_grid_are_counted_in_a_note(method):
    table = casest.lookup_table("CL", [GRID], LIFT, method)
    model, data, est, a = _fit(table, upper=0.6)
    b_hat = est.theta[model.parameter_names.index("b")]
    expected = int(np.sum(a + b_hat > 0.5) + np.sum(a + b_hat < -0.5))
    notes = [n for n in est.notes if n.code is NoteCode.TABLE_RANGE]
    assert expected > 0 and len(notes) == 1
    assert f"at {expected} of 500 samples" in notes[0] and "'CL'" in notes[0]
    (coverage,) = casest.table_coverage(model, data, est.theta)
    assert coverage.known and coverage.outside == expected and coverage.grid == (-0.5, 0.5)
    assert coverage.reached[1] == pytest.approx(a.max() + b_hat)


def test_a_record_inside_the_grid_gets_no_note():
    model, data, est, _ = _fit(casest.lookup_table("CL", [GRID], LIFT), upper=0.4)
    assert not [n for n in est.notes if n.code is NoteCode.TABLE_RANGE]
    assert casest.table_coverage(model, data, est.theta)[0].outside == 0


def test_a_raw_casadi_table_is_named_as_unchecked():
    _, _, est, _ = _fit(ca.interpolant("CLraw", "linear", [GRID], LIFT), upper=0.6)
    (note,) = [n for n in est.notes if n.code is NoteCode.TABLE_RANGE]
    assert "'CLraw'" in note and "casest.lookup_table" in note


def test_a_two_dimensional_table_counts_each_argument():
    """CD(alpha, mach) on alpha in [-0.5, 0.5], mach in [0, 0.8]: the record's mach reaches 0.9."""
    mach_grid = np.linspace(0.0, 0.8, 9)
    values = (0.02 + 0.1 * GRID[:, None] ** 2) * (1 + 0.2 * mach_grid[None, :])
    table = casest.lookup_table("CD", [GRID, mach_grid], values.ravel(order="F"), "linear")
    alpha, mach, k = ca.SX.sym("alpha"), ca.SX.sym("mach"), ca.SX.sym("k")
    model = casest.Model([P("k", nominal=1.0)], ["alpha", "mach"], {"CDm": k * table(ca.vertcat(alpha, mach))})
    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(-0.4, 0.4, 300), rng.uniform(0.0, 0.9, 300)])
    coverage = casest.table_coverage(model, casest.Dataset.from_arrays(model, X, np.zeros((300, 1))), [1.0])
    assert [c.dimension for c in coverage] == [0, 1]
    assert coverage[0].outside == 0 and coverage[1].outside == int(np.sum(X[:, 1] > 0.8))


@pytest.mark.parametrize("grid, values, method, message", [
    ([[0.0, 0.0, 1.0]], [1.0, 2.0, 3.0], "linear", "strictly increasing"),
    ([[0.0, np.nan, 1.0]], [1.0, 2.0, 3.0], "linear", "finite"),
    ([[0.0, 1.0]], [1.0, 2.0, 3.0], "linear", "3 values for a grid of"),
    ([[0.0, 1.0]], [1.0, 2.0], "cubic", "method must be 'linear' or 'bspline'"),
])
def test_lookup_table_refuses_a_bad_grid_with_the_fix(grid, values, method, message):
    with pytest.raises(ModelError, match=message):
        casest.lookup_table("T", grid, values, method)
