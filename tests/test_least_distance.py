"""Filter error's least-distance step (casest.filter_error.least_distance) on random convex QPs
whose feasibility is known by construction (scripts/campaigns/least_distance_check.py draws
them: scales over several decades, half with a contradictory pair of rows), with seed 20261204,
not the campaign's default seed 7 that the tolerances were examined on. Every infeasible problem
must get no step; every feasible one a step that meets each row to 1e-9 of its terms, satisfies
the KKT conditions and reaches qpOASES's optimal value (an independent active-set solver) to
1e-9 of the objective's terms."""

import numpy as np

from casest.filter_error.least_distance import FEASIBILITY_TOLERANCE, least_distance_step, relative_violation
from least_distance_check import check


def test_a_thousand_random_qps_feasible_and_infeasible_against_construction_and_qpoases():
    counts = check(problems=1000, seed=20261204)
    assert counts["feasible"] > 400 and counts["infeasible"] > 400, counts
    assert counts["infeasible given a step"] == 0, counts
    assert counts["feasible refused"] == 0, counts
    assert counts["KKT fails"] == 0, counts
    assert counts["objective above qpOASES's"] == 0, counts


def test_a_step_lands_on_an_active_bound_exactly():
    """min 1/2 d'd + g'd with g pushing d_0 below its bound -w_0 = -3.3e-10 (a process noise at
    3.3e-10 with lower bound 0): the step is -w_0 bit for bit, so w + d is exactly the bound."""
    w0 = 3.2655990754775e-10
    M = np.diag([1.7e-4, 2e8])
    g = np.array([1.0, -3.0])
    A, b = np.array([[-1.0, 0.0]]), np.array([w0])
    d, multipliers = least_distance_step(M, g, A, b)
    assert w0 + d[0] == 0.0
    assert abs(d[1] - 3.0 / 2e8) <= 1e-12 * 3.0 / 2e8  # the free unknown's Newton step (1e-13 regularised)
    np.testing.assert_allclose(multipliers, [1.0 - 1.7e-4 * w0], rtol=1e-12)


def test_a_contradiction_far_below_the_rows_size_in_absolute_terms_is_still_found():
    """Rows of size 1e-6 whose contradiction is 1e-12 in absolute terms (1e-6 of the rows' terms):
    an absolute test at 1e-12 misses it; no step is returned."""
    a = np.array([1e-6, -2e-6])
    A, b = np.vstack([a, -a]), np.array([1e-6, -1e-6 - 1e-12])
    d, _ = least_distance_step(np.eye(2), np.zeros(2), A, b)
    assert d is None
    d, _ = least_distance_step(np.eye(2), np.zeros(2), A, np.array([1e-6, -1e-6]))
    assert d is not None and np.max(relative_violation(A, np.array([1e-6, -1e-6]), d)) <= FEASIBILITY_TOLERANCE
