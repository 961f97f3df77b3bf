"""Filter error in the practice (innovation) formulation: formulation="innovation".

Truths: a hand-written NumPy implementation of the practice algorithm for the closed-loop
oscillator of test_filters (its RK4 step with two substeps as matrices; the continuous Riccati
equation A P + P A' - P C' R^-1 C P / dt + F F' = 0 by scipy.linalg.solve_continuous_are; the
closed-form innovation covariance; Jategaonkar's Eq. 5.41 F compensation; the inner minimisation
by Gauss-Newton with central-difference sensitivities, as the textbook's program does, where
diag(K C) <= 1 is not active): the same cost to 1e-10 at given values, the same estimate
to 1e-6; and the simulated truth of 12 records, every estimate within 3 std.
"""

import numpy as np
import pytest
from scipy.linalg import solve_continuous_are

import casest
from casest.state.innovation_filter_error import _Graph
from test_filters import LOOP_DT, LOOP_Q, LOOP_TRUTH, loop_model, loop_record


def _matrices(a, k, b):
    A, B = np.array([[0.0, 1.0], [-k, -a]]), np.array([0.0, b])
    h = LOOP_DT / 2
    hA = h * A
    M = np.eye(2) + hA + hA @ hA / 2 + hA @ hA @ hA / 6 + hA @ hA @ hA @ hA / 24
    G = h * (np.eye(2) + hA / 2 + hA @ hA / 6 + hA @ hA @ hA / 24) @ B
    return A, M @ M, M @ G + G


def numpy_innovations(data, a, k, b, f, R):
    """The innovations E (N, 2) and K C of the practice filter with the continuous Riccati's gain."""
    A, Phi, Gamma = _matrices(a, k, b)
    C = np.eye(2)
    P = solve_continuous_are(A.T, C.T, np.diag([0.0, f**2]), R * LOOP_DT)
    K = P @ C.T @ np.linalg.inv(R)
    x, E = np.zeros(2), []
    for y, u in zip(data.outputs, data.signals[:, 1]):
        e = y - C @ x
        E.append(e)
        x = Phi @ (x + K @ e) + Gamma * u
    return np.array(E), K @ C


def _gauss_newton(data, w, R):
    """The inner step as the textbook's program takes it: Gauss-Newton on 1/2 sum e' R^-1 e with
    central-difference sensitivities of the innovations (R held)."""
    Ri = np.linalg.inv(R)
    for _ in range(100):
        E, KC = numpy_innovations(data, *w, R)
        J = np.empty((E.size, w.size))
        for j in range(w.size):
            d = 1e-6 * max(1.0, abs(w[j]))
            up, down = w.copy(), w.copy()
            up[j] += d
            down[j] -= d
            J[:, j] = (numpy_innovations(data, *up, R)[0] - numpy_innovations(data, *down, R)[0]).reshape(-1) / (2 * d)
        W = np.kron(np.eye(len(E)), Ri)
        step = np.linalg.solve(J.T @ W @ J, -J.T @ W @ E.reshape(-1))
        w = w + step
        if np.max(np.abs(step) / np.maximum(np.abs(w), 1e-8)) < 1e-13:
            break
    assert np.all(np.diag(numpy_innovations(data, *w, R)[1]) < 1.0)  # the K C constraint is not active here
    return w


def numpy_practice_algorithm(data, start, f0):
    """The relaxation: the inner step with R held, R = E'E / N, Eq. 5.41, until J and w settle."""
    N = data.n_samples
    R = np.cov(data.outputs.T, bias=True)
    E, _ = numpy_innovations(data, *start, f0, R)
    R = E.T @ E / N
    w, J_prev, previous = np.array([*start, f0]), np.inf, None
    for _ in range(200):
        w = _gauss_newton(data, w, R)
        E, _ = numpy_innovations(data, *w, R)
        R_new = E.T @ E / N
        ri_old, ri_new = np.diag(np.linalg.inv(R)), np.diag(np.linalg.inv(R_new))
        w[3] *= ri_old[1] * np.sqrt(ri_old[1] / ri_new[1]) / ri_old[1]  # Eq. 5.41 with C = I: F on v
        J = 0.5 * N * 2 + 0.5 * N * np.log(np.linalg.det(R_new))
        moved = np.max(np.abs(w - previous) / np.maximum(np.abs(w), 1e-8)) if previous is not None else np.inf
        R, previous = R_new, w.copy()
        if abs(J - J_prev) <= 1e-12 * max(1.0, abs(J)) and moved <= 1e-9:
            break
        J_prev = J
    return w


def test_the_cost_equals_the_numpy_practice_filter():
    model = loop_model()
    data = loop_record(model, 3, N=300)
    theta, f, R = np.array([0.8, 3.5, 1.2]), 0.3, np.array([[2e-4, 1e-5], [1e-5, 6e-4]])
    graph = _Graph(model, data, np.zeros(2), data.signals[0, 1:], LOOP_DT)
    cost, E, kc, *_ = graph.functions(theta, [0.0, f], np.linalg.inv(R))
    E_np, KC = numpy_innovations(data, *theta, f, R)
    np.testing.assert_allclose(np.asarray(E).T, E_np, rtol=1e-10, atol=1e-13)
    assert float(cost) == pytest.approx(0.5 * np.einsum("ki,ij,kj->", E_np, np.linalg.inv(R), E_np), rel=1e-10)
    np.testing.assert_allclose(np.asarray(kc).reshape(-1), np.diag(KC), rtol=1e-10)


def test_the_estimate_equals_the_numpy_practice_algorithm():
    model = loop_model()
    data = loop_record(model, 1, N=400)
    fe = casest.filter_error_estimate(model, data, {"v": 0.1}, formulation="innovation")
    reference = numpy_practice_algorithm(data, model.nominal, np.sqrt(0.1))
    assert fe.success, fe.notes
    np.testing.assert_allclose(fe.theta, reference[:3], rtol=1e-6)
    assert np.sqrt(fe.process_noise["v"]) == pytest.approx(reference[3], rel=1e-6)


def test_twelve_records_recover_the_truth_within_three_std():
    """Coverage over seeds 0-11 (800 samples each): every parameter within 3 std."""
    model = loop_model()
    truth = model.vector(LOOP_TRUTH)
    z = []
    for seed in range(12):
        fe = casest.filter_error_estimate(model, loop_record(model, seed, N=800), {"v": 0.1}, formulation="innovation")
        assert fe.success, (seed, fe.notes)
        z.append((fe.theta - truth) / fe.std)
    z = np.array(z)
    assert np.all(np.abs(z) < 3), z
    assert np.all(np.abs(z.mean(axis=0)) < 0.75), z.mean(axis=0)


def test_the_innovation_form_estimates_its_own_noise():
    model = loop_model()
    with pytest.raises(casest.OptionError, match="leave R out"):
        casest.filter_error_estimate(model, loop_record(model, 0, N=200), {"v": LOOP_Q}, formulation="innovation",
                                     R=[1e-4, 4e-4])
