"""Stage 1 with candidates whose Gram matrix is exactly singular.

Truth: a sum of two exponentials whose data start at x = 0 with bounded amplitudes (the
candidates with equal rates, or both at the box edge, have coinciding columns); the linear
least squares of such a candidate has a least-norm solution, and the estimate must go on.
"""

import numpy as np
import casadi as ca

import casest
from casest.backend.least_squares import box_least_squares, gram_factor, solve_stack


def test_a_singular_system_in_the_stack_gets_its_least_norm_solution():
    K = np.array([[[2.0, 0.0], [0.0, 4.0]], [[1.0, 1.0], [1.0, 1.0]]])  # the second is singular
    rhs = np.array([[2.0, 4.0], [2.0, 2.0]])
    x = solve_stack(K, rhs)
    np.testing.assert_allclose(x[0], [1.0, 1.0])
    np.testing.assert_allclose(x[1], [1.0, 1.0])  # the least-norm solution of x1 + x2 = 2
    F = gram_factor(K[1])
    np.testing.assert_allclose(F.T @ F, K[1], atol=1e-12)


def test_bounded_least_squares_of_a_stack_with_a_singular_gram_matrix():
    P = np.array([[[1.0, 1.0], [1.0, 1.0]], [[2.0, 0.5], [0.5, 1.0]]])
    q = np.array([[3.0, 3.0], [1.0, 1.0]])
    x = box_least_squares(P, q, np.array([-1.0, -1.0]), np.array([1.0, 1.0]))
    assert np.all(np.isfinite(x)) and np.all(np.abs(x) <= 1.0 + 1e-12)
    np.testing.assert_allclose(x[0], [1.0, 1.0], atol=1e-9)  # the box's best point of x1 + x2 -> 3
    np.testing.assert_allclose(x[1], np.linalg.solve(P[1], q[1]), atol=1e-9)


def test_bounded_amplitudes_on_exponentials_from_zero_do_not_end_stage_one():
    x = np.linspace(0, 300, 33)
    y = 0.375 + 1.936 * np.exp(-0.0129 * x) - 1.465 * np.exp(-0.0221 * x)
    b = [ca.SX.sym(f"b{i}") for i in range(1, 6)]
    xs = ca.SX.sym("x")
    h = b[0] + b[1] * ca.exp(-xs * b[3]) + b[2] * ca.exp(-xs * b[4])
    params = [casest.Parameter(f"b{i}", lb=-1e3, ub=1e3, nominal=0.0) for i in (1, 2, 3)] + \
             [casest.Parameter(f"b{i}", lb=1e-4, ub=10.0, nominal=1.0) for i in (4, 5)]
    m = casest.Model(params, [casest.Signal("x")], {"y": h})
    data = casest.Dataset(m, {"x": x, "y": y + 1e-3 * np.random.default_rng(0).standard_normal(x.size)})
    est = casest.estimate(m, data)
    assert est.landscape is not None and np.all(np.isfinite(est.theta))
    assert est.cost <= casest.Problem(m, data).profile_cost(m.vector({"b1": 0.375, "b2": 1.936, "b3": -1.465,
                                                                       "b4": 0.0129, "b5": 0.0221})) + 1e-6
