"""The L D L' solver of SX matrices (casest._casadi.symbolic_algebra.ldl_solver) against NumPy's
dense algebra on random symmetric positive definite matrices (seed 20261203), and its signal for
a matrix that is not positive definite (a log-determinant that is not finite, a pivot that is
not positive)."""

import casadi as ca
import numpy as np
import pytest

from casest._casadi.symbolic_algebra import ldl_solver, symmetric_product


def _functions(k: int, p: int) -> ca.Function:
    S, B, b = ca.SX.sym("S", k, k), ca.SX.sym("B", k, p), ca.SX.sym("b", k)
    solve, quadratic, logdet, pivots = ldl_solver(S)
    return ca.Function("ldl", [S, B, b], [solve(B), quadratic(b), logdet, pivots])


@pytest.mark.parametrize("k", [1, 2, 3, 5, 12])
def test_ldl_solver_matches_dense_algebra_on_random_matrices(k):
    rng = np.random.default_rng(20261203 + k)
    f = _functions(k, 3)
    for _ in range(20):
        # condition numbers up to 1e8: eigenvalues spread over eight decades
        Q, _ = np.linalg.qr(rng.standard_normal((k, k)))
        S = Q @ np.diag(10.0 ** rng.uniform(-4, 4, k)) @ Q.T
        S = 0.5 * (S + S.T)
        B, b = rng.standard_normal((k, 3)), rng.standard_normal(k)
        X, quad, logdet, pivots = (np.asarray(v) for v in f(S, B, b))
        cond = np.linalg.cond(S)
        # a backward-stable solve: relative error within a modest multiple of cond * eps
        exact = np.linalg.solve(S, B)
        assert np.linalg.norm(X - exact) <= 100 * k * cond * 2.2e-16 * np.linalg.norm(exact)
        assert quad.item() == pytest.approx(b @ np.linalg.solve(S, b), rel=100 * k * cond * 2.2e-16)
        assert logdet.item() == pytest.approx(np.linalg.slogdet(S)[1], rel=1e-10, abs=1e-10 * k)
        # the pivots are D of S = L D L': their logarithms sum to the log-determinant
        assert np.all(pivots > 0) and np.sum(np.log(pivots)) == pytest.approx(logdet.item(), rel=1e-12, abs=1e-12)


def test_ldl_solver_log_determinant_not_finite_without_positive_definiteness():
    f = _functions(3, 1)
    for S in (np.diag([1.0, -1.0, 2.0]), np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
              np.diag([1.0, 0.0, 1.0])):
        values = f(S, np.ones((3, 1)), np.ones(3))
        assert not np.isfinite(float(values[2]))
        # and a pivot that is not positive says so without a logarithm (the C export's check)
        assert not np.all(np.asarray(values[3]) > 0)


def test_symmetric_product_is_exactly_symmetric():
    rng = np.random.default_rng(20261203)
    A, B = ca.SX.sym("A", 3, 4), ca.SX.sym("B", 4, 4)
    f = ca.Function("f", [A, B], [symmetric_product(A, B)])
    a, b = rng.standard_normal((3, 4)), rng.standard_normal((4, 4))
    b = b + b.T
    out = np.asarray(f(a, b))
    assert np.array_equal(out, out.T)
    np.testing.assert_allclose(out, a @ b @ a.T, rtol=1e-12, atol=1e-12 * np.abs(a @ b @ a.T).max())
