"""The Kalman filter with every matrix varying in time: Phi(k), Psi(k), Gamma(k), Q(k), C(k),
D(k), R(k), and missing channels.

Truth: the textbook filter (summary Eq. 2.7-2.11, covariance form, the missing channels' rows cut
out) written here as a plain NumPy loop, to 1e-12, for the compiled pass and for update/predict
from Python; the RTS smoother on the result equals the textbook RTS recursion given the same
per-interval Gamma(k) Q(k) Gamma(k)'.
"""

import numpy as np
import pytest

import casest
from casest.errors import OptionError


def _system(N=120, seed=0):
    rng = np.random.default_rng(seed)
    n, q, m, p = 3, 2, 1, 2
    k = np.arange(N)
    Phi = np.array([[[1.0, 0.1, 0.0], [-0.1 * (1 + 0.3 * np.sin(0.05 * i)), 0.95, 0.05], [0.0, 0.0, 0.9]] for i in k])
    Psi = np.array([[[0.0], [0.1 + 0.05 * np.cos(0.1 * i)], [0.02]] for i in k])
    Gamma = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0 + 0.5 * np.sin(0.03 * i)]] for i in k])
    Q = np.array([np.diag([0.01 * (1 + 0.5 * np.sin(0.07 * i)), 0.002]) for i in k])
    C = np.array([[[1.0, 0.0, 0.2 * np.cos(0.02 * i)], [0.0, 1.0, 0.0]] for i in k])
    D = np.array([[[0.05 * np.sin(0.04 * i)], [0.0]] for i in k])
    R = np.array([[[0.02 + 0.01 * np.sin(0.05 * i), 0.003], [0.003, 0.04]] for i in k])
    u = np.sin(0.2 * k)[:, None]
    y = rng.normal(0.0, 0.2, (N, q)) + np.column_stack([np.sin(0.1 * k), np.cos(0.13 * k)])
    y[rng.random(y.shape) < 0.1] = np.nan
    y[7] = np.nan
    return dict(Phi=Phi, Psi=Psi, Gamma=Gamma, Q=Q, C=C, D=D, R=R), u, y, (n, q, m, p)


def _textbook(M, u, y, x0, P0):
    x, P = x0.copy(), P0.copy()
    xs, Ps = [], []
    for k in range(len(y)):
        seen = np.isfinite(y[k])
        if seen.any():
            C, R = M["C"][k][seen], M["R"][k][np.ix_(seen, seen)]
            S = C @ P @ C.T + R
            K = P @ C.T @ np.linalg.inv(S)
            x = x + K @ (y[k][seen] - C @ x - M["D"][k][seen] @ u[k])
            P = (np.eye(len(x)) - K @ C) @ P
        xs.append(x)
        Ps.append(P)
        if k < len(y) - 1:
            G = M["Gamma"][k]
            x = M["Phi"][k] @ x + M["Psi"][k] @ u[k]
            P = M["Phi"][k] @ P @ M["Phi"][k].T + G @ M["Q"][k] @ G.T
    return np.array(xs), np.array(Ps)


@pytest.mark.parametrize("compiled", [True, False])
def test_every_matrix_varying_equals_the_textbook_filter(compiled):
    M, u, y, (n, q, m, p) = _system()
    x0, P0 = np.zeros(n), np.eye(n) * 0.5
    kf = casest.KalmanFilter(M["Phi"], M["C"], M["Q"], M["R"], x0, P0, Psi=M["Psi"], D=M["D"], Gamma=M["Gamma"])
    assert kf.time_varying
    result = kf.filter(y, u, compiled=compiled)
    xs, Ps = _textbook(M, u, y, x0, P0)
    np.testing.assert_allclose(result.x_filtered, xs, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(result.P_filtered, Ps, rtol=1e-10, atol=1e-12)


def test_only_the_noise_varying_is_time_varying_too():
    """Constant Phi, C and a per-sample R: the compiled pass carries R(k) with each sample."""
    M, u, y, (n, q, m, p) = _system(seed=1)
    x0, P0 = np.zeros(n), np.eye(n) * 0.5
    constant = {k: (v if k in ("R",) else np.broadcast_to(v[0], v.shape).copy()) for k, v in M.items()}
    kf = casest.KalmanFilter(M["Phi"][0], M["C"][0], M["Q"][0], M["R"], x0, P0, Psi=M["Psi"][0], D=M["D"][0],
                             Gamma=M["Gamma"][0])
    xs, _ = _textbook(constant, u, y, x0, P0)
    np.testing.assert_allclose(kf.filter(y, u).x_filtered, xs, rtol=1e-10, atol=1e-12)


def test_the_smoother_on_a_time_varying_record_equals_the_textbook_rts():
    M, u, y, (n, q, m, p) = _system(seed=2)
    x0, P0 = np.zeros(n), np.eye(n) * 0.5
    kf = casest.KalmanFilter(M["Phi"], M["C"], M["Q"], M["R"], x0, P0, Psi=M["Psi"], D=M["D"], Gamma=M["Gamma"])
    result = kf.filter(y, u)
    smoothed = casest.rts_smoother(result)
    xs, Ps = result.x_filtered.copy(), result.P_filtered.copy()
    for k in range(len(y) - 2, -1, -1):  # Eq. 2.20, 2.22 with the filter's own P(k+1|k)
        G = result.P_filtered[k] @ M["Phi"][k].T @ np.linalg.inv(result.P_predicted[k + 1])
        xs[k] = result.x_filtered[k] + G @ (xs[k + 1] - result.x_predicted[k + 1])
        Ps[k] = result.P_filtered[k] + G @ (Ps[k + 1] - result.P_predicted[k + 1]) @ G.T
    np.testing.assert_allclose(smoothed.x, xs, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(smoothed.P, Ps, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("change, message", [
    ({"D": np.zeros((5, 3, 1))}, r"D must have shape \(2, 1\) or \(K, 2, 1\)"),
    ({"Gamma": np.zeros((5, 2, 2))}, r"Gamma must have shape \(3, 2\) or \(K, 3, 2\)"),
    ({"Q": np.zeros((5, 3, 3))}, r"Q must have shape \(2, 2\), \(2,\) or \(K, 2, 2\)"),
    ({"R": -np.ones((5, 2, 2)) * np.eye(2)}, r"R must be positive semi-definite at every sample; it is not at samples \[0, 1"),
])
def test_time_varying_shapes_and_values_are_named(change, message):
    M, u, y, (n, q, m, p) = _system()
    args = {**{k: v[:5] for k, v in M.items()}, **change}
    with pytest.raises(OptionError, match=message):
        casest.KalmanFilter(args["Phi"], args["C"], args["Q"], args["R"], np.zeros(n), np.eye(n), Psi=args["Psi"],
                            D=args["D"], Gamma=args["Gamma"])
