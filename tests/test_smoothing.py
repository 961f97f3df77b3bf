"""Process-noise smoothing, the single-stage smoother and the continuous-to-discrete conversion.

Truths: (1) the smoothed states and process noise are the mean and covariance of the Gaussian
posterior of [x(0); w(0) ... w(N-2)] given every measurement, computed densely in NumPy from
the stacked linear model (an independent derivation, not the recursions of Eq. 2.20-2.23);
(2) the single-stage smoother equals Eq. 2.14-2.15 (the innovation form) and the RTS
smoother of the first two samples; (3) Phi and Psi equal scipy.signal.cont2discrete (zoh) and
Q_d equals the quadrature of its defining integral (scipy.integrate.quad_vec).
"""

import numpy as np
import pytest
from scipy.integrate import quad_vec
from scipy.linalg import expm
from scipy.signal import cont2discrete

import casest
from casest.filters.ekf import rts_smoother
from casest.filters.smoothing import continuous_to_discrete, single_stage_smoother

RNG = np.random.default_rng(5)
N, n, p, q, m = 25, 3, 2, 2, 1
A = RNG.standard_normal((n, n))
PHI = 0.9 * A / np.max(np.abs(np.linalg.eigvals(A)))
C, PSI, D, GAMMA = RNG.standard_normal((q, n)), RNG.standard_normal((n, m)), RNG.standard_normal((q, m)), \
    RNG.standard_normal((n, p))
Q, R = np.diag([0.05, 0.2]), np.diag([0.1, 0.3])
X0, P0 = np.array([0.3, -0.1, 0.2]), np.diag([0.5, 0.4, 0.3])
U = np.sin(0.3 * np.arange(N))[:, None]


def record(seed=1):
    rng = np.random.default_rng(seed)
    x, Y = rng.multivariate_normal(X0, P0), []
    for k in range(N):
        Y.append(C @ x + D @ U[k] + rng.multivariate_normal(np.zeros(q), R))
        x = PHI @ x + PSI @ U[k] + GAMMA @ rng.multivariate_normal(np.zeros(p), Q)
    return np.array(Y)


def batch_posterior(Y):
    """Mean and covariance of z = [x0; w_0 .. w_{N-2}] given Y, and the maps x_k = M_k z + c_k."""
    dim = n + p * (N - 1)
    M, c = np.zeros((N, n, dim)), np.zeros((N, n))
    M[0, :, :n] = np.eye(n)
    c[0] = 0.0
    for k in range(N - 1):
        M[k + 1] = PHI @ M[k]
        M[k + 1][:, n + p * k:n + p * (k + 1)] += GAMMA
        c[k + 1] = PHI @ c[k] + PSI @ U[k]
    prior_mean = np.concatenate([X0, np.zeros(p * (N - 1))])
    prior_cov = np.zeros((dim, dim))
    prior_cov[:n, :n] = P0
    for k in range(N - 1):
        prior_cov[n + p * k:n + p * (k + 1), n + p * k:n + p * (k + 1)] = Q
    H = np.vstack([C @ M[k] for k in range(N)])
    offset = np.concatenate([C @ c[k] + D @ U[k] for k in range(N)])
    Rinv = np.kron(np.eye(N), np.linalg.inv(R))
    cov = np.linalg.inv(np.linalg.inv(prior_cov) + H.T @ Rinv @ H)
    mean = cov @ (np.linalg.solve(prior_cov, prior_mean) + H.T @ Rinv @ (Y.reshape(-1) - offset))
    return mean, cov, M, c


def test_smoothed_states_and_process_noise_are_the_batch_posterior():
    Y = record()
    kf = casest.KalmanFilter(PHI, C, Q, R, X0, P0, Psi=PSI, D=D, Gamma=GAMMA)
    result = kf.filter(Y, U)
    smooth = rts_smoother(result, process_noise=Q, noise_input=GAMMA)
    mean, cov, M, c = batch_posterior(Y)
    for k in range(N):
        np.testing.assert_allclose(smooth.x[k], M[k] @ mean + c[k], rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(smooth.P[k], M[k] @ cov @ M[k].T, rtol=1e-9, atol=1e-10)
    for k in range(N - 1):
        block = slice(n + p * k, n + p * (k + 1))
        np.testing.assert_allclose(smooth.w[k], mean[block], rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(smooth.Q[k], cov[block, block], rtol=1e-9, atol=1e-10)
    assert np.all(np.linalg.eigvalsh(Q - smooth.Q) > -1e-12)  # the data never add noise uncertainty


def test_the_single_stage_smoother_is_eq_2_14_and_2_15():
    Y = record(2)
    kf = casest.KalmanFilter(PHI, C, Q, R, X0, P0, Psi=PSI, Gamma=GAMMA)  # Eq. 2.14 has no feed-through
    result = kf.filter(Y, U)
    for k in (0, 7):
        one = single_stage_smoother(result, k, Q, GAMMA)
        innovation = np.linalg.solve(R, Y[k + 1] - C @ result.x_filtered[k + 1])
        x = result.x_filtered[k] + result.P_filtered[k] @ PHI.T @ C.T @ innovation      # Eq. 2.14
        w = Q @ GAMMA.T @ C.T @ innovation                                               # Eq. 2.15
        np.testing.assert_allclose(one["x"], x, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(one["w"], w, rtol=1e-10, atol=1e-12)
    two = casest.KalmanFilter(PHI, C, Q, R, X0, P0, Psi=PSI, Gamma=GAMMA).filter(Y[:2], U[:2])
    rts = rts_smoother(two, process_noise=Q, noise_input=GAMMA)
    one = single_stage_smoother(two, 0, Q, GAMMA)
    np.testing.assert_allclose(one["P"], rts.P[0], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(one["Q"], rts.Q[0], rtol=1e-10, atol=1e-12)
    with pytest.raises(casest.OptionError, match="0 <= k <= 0, got 1"):
        single_stage_smoother(two, 1, Q, GAMMA)


def test_continuous_to_discrete_against_scipy_and_the_integral():
    Ac = np.array([[0.0, 1.0], [-4.0, -0.6]])
    B, G, Qc, dt = np.array([[0.0], [1.0]]), np.array([[0.0], [1.0]]), np.array([[0.3]]), 0.05
    Phi, Psi, Qd = continuous_to_discrete(Ac, B, G, Qc, dt)
    Phi_ref, Psi_ref, *_ = cont2discrete((Ac, B, np.eye(2), np.zeros((2, 1))), dt, method="zoh")
    np.testing.assert_allclose(Phi, Phi_ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(Psi, Psi_ref, rtol=1e-12, atol=1e-14)
    integral, _ = quad_vec(lambda s: expm(Ac * s) @ G @ Qc @ G.T @ expm(Ac.T * s), 0.0, dt, epsabs=1e-15)
    np.testing.assert_allclose(Qd, integral, rtol=1e-9, atol=1e-15)
    with pytest.raises(casest.OptionError, match="positive number of seconds"):
        continuous_to_discrete(Ac, B, G, Qc, 0.0)


def test_the_ekf_smoother_carries_the_process_noise_that_closes_the_dynamics():
    """For a linear model the EKF is the Kalman filter, and the smoothed states obey the step with
    the smoothed noise: x(k+1|N) = step(x(k|N)) + w(k|N) (Gamma = I), an identity of Eq. 2.20-2.21."""
    import casadi as ca

    x, v, u, k_, c_ = (ca.SX.sym(s) for s in ("x", "v", "u", "k", "c"))
    P = casest.Parameter
    model = casest.DynamicModel([P("k", 0.5, 8.0, 2.0), P("c", 0.0, 2.0, 0.3)],
                                [casest.State("x", 0.2), casest.State("v", 0.0)], ["u"],
                                {"x": v, "v": -k_ * x - c_ * v + u}, {"y": x}, input_hold="zoh")
    t = np.arange(200) * 0.05
    rng = np.random.default_rng(3)
    data = model.dataset({"t": t, "u": np.sin(0.9 * t), "y": 0.2 * np.cos(1.4 * t) + 0.02 * rng.standard_normal(t.size)})
    ekf = casest.ExtendedKalmanFilter(model, {"k": 2.0, "c": 0.3}, {"v": 0.05}, [0.02**2], np.eye(2) * 1e-3)
    result, smooth = ekf.smooth(data)
    assert smooth.w.shape == (199, 2) and smooth.Q.shape == (199, 2, 2)
    step = model.step_function
    theta = model.vector({"k": 2.0, "c": 0.3})
    Ua, Ub = model.interval_input_values(data.signals[:, 1:])
    for k in (0, 50, 198):
        predicted = np.asarray(step(smooth.x[k], Ua[k], Ub[k], 0.05, theta)).reshape(-1)
        np.testing.assert_allclose(smooth.x[k + 1], predicted + smooth.w[k], rtol=1e-8, atol=1e-11)


def test_ekf_prediction_ahead_repeats_the_time_update_and_leaves_the_filter():
    """Truth: the time update applied step by step on a copy (Eq. 3.10-3.11 repeated)."""
    import casadi as ca

    x, v, u, k_ = (ca.SX.sym(s) for s in ("x", "v", "u", "k"))
    model = casest.DynamicModel([casest.Parameter("k", 0.5, 8.0, 2.0)], [casest.State("x", 0.2), casest.State("v", 0.0)],
                                ["u"], {"x": v, "v": -k_ * ca.sin(x) + u}, {"y": x})
    ekf = casest.ExtendedKalmanFilter(model, {"k": 2.0}, {"v": 0.05}, [1e-4], np.eye(2) * 1e-3, x0=[0.3, -0.1])
    ekf.reset()
    xs, Ps = ekf.predict_ahead(5, 0.1, [0.4])
    np.testing.assert_array_equal(ekf.x, [0.3, -0.1])  # unchanged
    twin = casest.ExtendedKalmanFilter(model, {"k": 2.0}, {"v": 0.05}, [1e-4], np.eye(2) * 1e-3, x0=[0.3, -0.1])
    twin.reset()
    for i in range(5):
        x_i, P_i, _ = twin.predict(0.1, [0.4], [0.4], [0.4])
        np.testing.assert_allclose(xs[i], x_i, rtol=1e-14)
        np.testing.assert_allclose(Ps[i], P_i, rtol=1e-14)
    assert np.all(np.diff([np.trace(P) for P in Ps]) > 0)  # the uncertainty grows ahead
