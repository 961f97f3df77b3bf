"""Filter error in the practice (innovation) formulation: formulation="innovation".

Truths: a hand-written NumPy implementation of the practice algorithm for the closed-loop
oscillator of test_filters (its RK4 step with two substeps as matrices; the continuous Riccati
equation A P + P A' - P C' R^-1 C P / dt + F F' = 0 by scipy.linalg.solve_continuous_are; the
closed-form innovation covariance; Jategaonkar's Eq. 5.41 F compensation; the inner minimisation
by Gauss-Newton with the innovations' sensitivities by their own recursion, where
diag(K C) <= 1 is not active): the same innovations to 1e-10 at given values, the same estimate
to 1e-8 with the gain at the first operating point and renewed at the mean one (the model is
linear: the two points give one gain); and the simulated truth of 12 records, every estimate
within 3 std.
"""

import numpy as np
import pytest
from scipy.linalg import solve_continuous_are, solve_continuous_lyapunov

import casest
from casest._casadi.numerics import compiler_available
from casest.filter_error.gain_sensitivities import GainPassDerivatives
from casest.filter_error.innovation import InnovationProblem
from casest.filter_error.scoring import InnovationDerivatives
from test_filters import LOOP_DT, LOOP_Q, LOOP_TRUTH, loop_model, loop_record


def _matrices(a, k, b):
    A, B = np.array([[0.0, 1.0], [-k, -a]]), np.array([0.0, b])
    h = LOOP_DT / 2
    hA = h * A
    M = np.eye(2) + hA + hA @ hA / 2 + hA @ hA @ hA / 6 + hA @ hA @ hA @ hA / 24
    G = h * (np.eye(2) + hA / 2 + hA @ hA / 6 + hA @ hA @ hA / 24) @ B
    return A, M @ M, M @ G + G


def _gain(A, f, R, dA=None, dFF=None):
    """K = P C' R^-1 (C = I) from the continuous Riccati equation A P + P A' - P M P + F F' = 0,
    M = R^-1 / dt: SciPy's solution refined by one Newton-Kleinman step; with ``dA`` and ``dFF``
    (stacks over the parameters) also dK from the Lyapunov equation of the derivative."""
    M, FF = np.linalg.inv(R) / LOOP_DT, np.diag([0.0, f**2])
    P = solve_continuous_are(A.T, np.eye(2), FF, R * LOOP_DT)
    closed = A - P @ M
    P = solve_continuous_lyapunov(closed, -(FF + P @ M @ P))
    K = P @ np.linalg.inv(R)
    if dA is None:
        return K, None
    closed = A - P @ M
    dP = [solve_continuous_lyapunov(closed, -(a @ P + P @ a.T + q)) for a, q in zip(dA, dFF)]
    return K, np.array([d @ np.linalg.inv(R) for d in dP])


def numpy_innovations(data, a, k, b, f, R, sensitivities=False):
    """The innovations E (N, 2), K C and (with ``sensitivities``) dE/dw (N, 2, 4) of the practice
    filter: x+ = Phi (x + K e) + Gamma u, e = y - x; the sensitivities by their own recursion
    (dPhi, dGamma and dA by complex steps of the polynomial RK4 matrices, dK from the Riccati
    equation's derivative)."""
    A, Phi, Gamma = _matrices(a, k, b)
    dA = dPhi = dGamma = dFF = None
    if sensitivities:
        w, dA, dPhi, dGamma = np.array([a, k, b], dtype=complex), [], [], []
        for j in range(3):
            v = w.copy()
            v[j] += 1e-30j
            parts = _matrices(*v)
            dA.append(parts[0].imag / 1e-30), dPhi.append(parts[1].imag / 1e-30), dGamma.append(parts[2].imag / 1e-30)
        dA, dPhi, dGamma = dA + [np.zeros((2, 2))], dPhi + [np.zeros((2, 2))], dGamma + [np.zeros(2)]
        dFF = [np.zeros((2, 2))] * 3 + [np.diag([0.0, 2 * f])]
    K, dK = _gain(A, f, R, dA, dFF)
    x, dx, E, dE = np.zeros(2), np.zeros((2, 4)), [], []
    for y, u in zip(data.outputs, data.signals[:, 1]):
        e = y - x
        E.append(e)
        if sensitivities:
            de = -dx
            dE.append(de)
            post = x + K @ e
            dx = np.stack([dPhi[j] @ post + Phi @ (dx[:, j] + dK[j] @ e + K @ de[:, j]) + dGamma[j] * u
                           for j in range(4)], axis=1)
        x = Phi @ (x + K @ e) + Gamma * u
    return np.array(E), K, (np.array(dE) if sensitivities else None)


def _gauss_newton(data, w, R):
    """The inner step as the textbook's program takes it: Gauss-Newton on 1/2 sum e' R^-1 e with
    the innovations' sensitivities (R held), until the step is below 1e-12 relative (30
    iterations at most)."""
    Ri = np.linalg.inv(R)
    for _ in range(30):
        E, _, dE = numpy_innovations(data, *w, R, sensitivities=True)
        M = np.einsum("kiv,ij,kjw->vw", dE, Ri, dE)
        step = np.linalg.solve(M, -np.einsum("kiv,ij,kj->v", dE, Ri, E))
        w = w + step
        if np.max(np.abs(step) / np.maximum(np.abs(w), 1e-8)) < 1e-12:
            break
    assert np.all(np.diag(numpy_innovations(data, *w, R)[1]) < 1.0)  # the K C constraint is not active here
    return w


def numpy_practice_algorithm(data, start, f0):
    """The relaxation with the full innovation covariance (``innovation_covariance="full"``): the inner step with R held, R = E'E / N, Eq. 5.41, until J moves by less
    than 1e-13 relative and w by less than 1e-11 (tighter than casest's own stop)."""
    N = data.n_samples
    R = np.cov(data.outputs.T, bias=True)
    E, *_ = numpy_innovations(data, *start, f0, R)
    R = E.T @ E / N
    w, J_prev, previous = np.array([*start, f0]), np.inf, None
    for _ in range(60):
        w = _gauss_newton(data, w, R)
        E, *_ = numpy_innovations(data, *w, R)
        R_new = E.T @ E / N
        ri_old, ri_new = np.diag(np.linalg.inv(R)), np.diag(np.linalg.inv(R_new))
        w[3] *= ri_old[1] * np.sqrt(ri_old[1] / ri_new[1]) / ri_old[1]  # Eq. 5.41 with C = I: F on v
        J = 0.5 * N * 2 + 0.5 * N * np.log(np.linalg.det(R_new))
        moved = np.max(np.abs(w - previous) / np.maximum(np.abs(w), 1e-8)) if previous is not None else np.inf
        R, previous = R_new, w.copy()
        if abs(J - J_prev) <= 1e-13 * max(1.0, abs(J)) and moved <= 1e-11:
            break
        J_prev = J
    return w


def test_the_innovations_equal_the_numpy_practice_filter():
    model = loop_model()
    data = loop_record(model, 3, N=300)
    theta, f, R = np.array([0.8, 3.5, 1.2]), 0.3, np.array([[2e-4, 1e-5], [1e-5, 6e-4]])
    problem = InnovationProblem.of(model, data.n_samples, (1,))
    p = problem.parameters(data, R, np.zeros(2), data.signals[0, 1:], np.array([0.0, f]))
    E, kc, *_ = problem.values(np.concatenate([theta / model.scales, [f]]), p)
    E_np, K, _ = numpy_innovations(data, *theta, f, R)
    np.testing.assert_allclose(np.asarray(E).T, E_np, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(np.asarray(kc).reshape(-1), np.diag(K), rtol=1e-10)


def test_the_compiled_sensitivity_loop_equals_the_graphs_jacobian():
    """dE/dw of the innovation pass by the compiled loop (the states' forward sensitivities chained
    with those of theta, K and x0) against CasADi's Jacobian of the record's graph, to 1e-10."""
    model = loop_model()
    data = loop_record(model, 4, N=250)
    R = np.array([[2e-4, 1e-5], [1e-5, 6e-4]])
    problem = InnovationProblem.of(model, data.n_samples, (1,))
    if not compiler_available():
        pytest.skip("the loop needs a C compiler")
    assert isinstance(problem.derivatives, GainPassDerivatives)
    E, S = problem.derivatives.innovations(problem.w, problem.p)
    graph = InnovationDerivatives(problem.w, problem.p, E, S)
    p = problem.parameters(data, R, np.zeros(2), data.signals[0, 1:], np.array([0.0, 0.3]))
    w = np.concatenate([np.array([0.8, 3.5, 1.2]) / model.scales, [0.3]])
    for loop_part, graph_part in zip(problem.derivatives(w, p), graph(w, p)):
        assert loop_part.shape == graph_part.shape
        np.testing.assert_allclose(loop_part, graph_part, rtol=1e-10, atol=1e-10 * max(np.abs(graph_part).max(), 1e-300))


@pytest.fixture(scope="module")
def reference_case():
    model = loop_model()
    data = loop_record(model, 1, N=400)
    return model, data, numpy_practice_algorithm(data, model.nominal, np.sqrt(0.1))


@pytest.mark.parametrize("operating_point", ["first", "mean"])
def test_the_estimate_equals_the_numpy_practice_algorithm(reference_case, operating_point):
    model, data, reference = reference_case
    # settle_std=0: the fixed point to rounding, as the reference iterates to it
    fe = casest.filter_error_estimate(model, data, {"v": 0.1}, formulation="innovation",
                                      operating_point=operating_point, innovation_covariance="full", settle_std=0)
    assert fe.success, fe.notes
    np.testing.assert_allclose(fe.theta, reference[:3], rtol=1e-8)
    assert np.sqrt(fe.process_noise["v"]) == pytest.approx(reference[3], rel=1e-8)
    assert fe.n_iterations >= 1 and "Gauss-Newton iterations in all" in fe.notes[0]


@pytest.mark.slow
def test_twelve_records_recover_the_truth_within_three_std():
    """Coverage of the full-covariance estimator over seeds 0-11 (800 samples each): every
    parameter within 3 std."""
    model = loop_model()
    truth = model.vector(LOOP_TRUTH)
    z = []
    for seed in range(12):
        fe = casest.filter_error_estimate(model, loop_record(model, seed, N=800), {"v": 0.1}, formulation="innovation",
                                          innovation_covariance="full")
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


def test_options_the_innovation_form_would_ignore_are_refused():
    """max_iter=0 would have run Gauss-Newton steps anyway; P0 does not enter a one-gain form."""
    model = loop_model()
    data = loop_record(model, 0, N=200)
    with pytest.raises(casest.OptionError, match="max_iter must be a whole number of solver steps >= 1"):
        casest.filter_error_estimate(model, data, {"v": LOOP_Q}, formulation="innovation", max_iter=0)
    with pytest.raises(casest.OptionError, match="P0 is not used by the 'innovation' formulation"):
        casest.filter_error_estimate(model, data, {"v": LOOP_Q}, formulation="innovation", P0=np.eye(2))


def test_the_kc_constraint_holds_where_it_binds(monkeypatch):
    """A record whose rate is measured almost without noise (std 5e-4): the unconstrained optimum
    has a gain above one on it, so diag(K C) <= 1 binds (IPOPT, its stop verified by the
    first-order conditions). Checked by the NumPy filter above at the estimate: the closed-form
    innovation covariance and the continuous Riccati gain give diag(K C) <= 1 + 1e-6, and the
    parameters lie within 3 std of the truth."""
    import test_filters

    monkeypatch.setattr(test_filters, "LOOP_NOISE", np.array([0.01, 0.0005]))
    model = loop_model()
    data = loop_record(model, 3, N=600)
    fe = casest.filter_error_estimate(model, data, {"v": 0.1}, formulation="innovation", innovation_covariance="full")
    assert fe.success, fe.notes
    assert "was active" in fe.notes[0]
    f = np.sqrt(fe.process_noise["v"])
    R = np.eye(2)
    for _ in range(30):  # the closed-form R at the estimate: the fixed point of R = E'E / N (~10 steps)
        E, K, _ = numpy_innovations(data, *fe.theta, f, R)
        R = E.T @ E / data.n_samples
    assert np.all(np.diag(K) <= 1.0 + 1e-6), np.diag(K)
    assert np.max(np.diag(K)) > 0.999  # it binds
    truth = model.vector(LOOP_TRUTH)
    assert np.all(np.abs(fe.theta - truth) < 3 * fe.std), (fe.theta, fe.std)
