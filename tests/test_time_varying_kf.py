"""KalmanFilter with time-varying Phi(k), Psi(k), C(k) (summary Eq. 2.1-2.11 with the
matrices indexed by the sample) against a textbook NumPy filter written here (standard
covariance update, not the Joseph form), and the RTS smoother against Eq. 2.20-2.22 by hand."""

import numpy as np
import pytest

import casest
from casest.filters.ekf import rts_smoother
from casest.filters.kalman import KalmanFilter

N, Q, R = 60, np.diag([1e-3, 2e-3]), np.array([[0.05]])


def _system(seed=0):
    """A damped oscillator whose frequency drifts, measured through a rotating output row."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) * 0.1
    omega = 1.0 + 0.5 * np.sin(0.3 * t[:-1])
    Phi = np.array([[[1.0, 0.1], [-0.1 * w ** 2, 0.98]] for w in omega])
    C = np.array([[[np.cos(0.05 * k), np.sin(0.05 * k)]] for k in range(N)])
    Psi = np.array([[[0.0], [0.1 * (1 + 0.01 * k)]] for k in range(N - 1)])
    u = rng.standard_normal((N, 1))
    x, y = np.array([1.0, 0.0]), np.empty((N, 1))
    for k in range(N):
        y[k] = C[k] @ x + np.sqrt(R[0, 0]) * rng.standard_normal(1)
        if k < N - 1:
            x = Phi[k] @ x + Psi[k] @ u[k] + rng.multivariate_normal(np.zeros(2), Q)
    y[[7, 20]] = np.nan
    return Phi, C, Psi, u, y


def _textbook(Phi, C, Psi, u, y, x0, P0):
    """x(k|k), P(k|k), x(k|k-1), P(k|k-1) with K = P C' S^-1, P+ = (I - K C) P."""
    x, P = x0.copy(), P0.copy()
    out = {"xf": [], "Pf": [], "xp": [], "Pp": []}
    for k in range(N):
        out["xp"].append(x.copy()); out["Pp"].append(P.copy())
        if np.isfinite(y[k]).all():
            S = C[k] @ P @ C[k].T + R
            K = P @ C[k].T @ np.linalg.inv(S)
            x = x + K @ (y[k] - C[k] @ x)
            P = (np.eye(2) - K @ C[k]) @ P
        out["xf"].append(x.copy()); out["Pf"].append(P.copy())
        if k < N - 1:
            x = Phi[k] @ x + Psi[k] @ u[k]
            P = Phi[k] @ P @ Phi[k].T + Q
    return {key: np.array(v) for key, v in out.items()}


@pytest.mark.parametrize("compiled", [True, False])
def test_time_varying_filter_equals_textbook(compiled):
    Phi, C, Psi, u, y = _system()
    x0, P0 = np.zeros(2), np.eye(2)
    result = KalmanFilter(Phi, C, Q, R, x0, P0, Psi=Psi).filter(y, u, compiled=compiled)
    ref = _textbook(Phi, C, Psi, u, y, x0, P0)
    np.testing.assert_allclose(result.x_filtered, ref["xf"], rtol=0, atol=1e-10)
    np.testing.assert_allclose(result.P_filtered, ref["Pf"], rtol=0, atol=1e-10)
    np.testing.assert_allclose(result.x_predicted, ref["xp"], rtol=0, atol=1e-10)
    np.testing.assert_allclose(result.transition, Phi, rtol=0, atol=0)
    # RTS by hand (Eq. 2.20, 2.22) with the time-varying Phi(k)
    xs, Ps = ref["xf"].copy(), ref["Pf"].copy()
    for k in range(N - 2, -1, -1):
        G = ref["Pf"][k] @ Phi[k].T @ np.linalg.inv(ref["Pp"][k + 1])
        xs[k] = ref["xf"][k] + G @ (xs[k + 1] - ref["xp"][k + 1])
        Ps[k] = ref["Pf"][k] + G @ (Ps[k + 1] - ref["Pp"][k + 1]) @ G.T
    smoothed = rts_smoother(result, compiled=compiled)
    np.testing.assert_allclose(smoothed.x, xs, rtol=0, atol=1e-9)
    np.testing.assert_allclose(smoothed.P, Ps, rtol=0, atol=1e-9)


def test_step_by_step_follows_the_sample_counter():
    Phi, C, Psi, u, y = _system(seed=1)
    whole = KalmanFilter(Phi, C, Q, R, np.zeros(2), np.eye(2), Psi=Psi).filter(y, u)
    online = KalmanFilter(Phi, C, Q, R, np.zeros(2), np.eye(2), Psi=Psi)
    for k in range(N):
        x, _ = online.update(y[k])
        np.testing.assert_allclose(x, whole.x_filtered[k], rtol=0, atol=1e-12)
        if k < N - 1:
            online.predict(u[k])
    assert online.sample == N - 1
    # a record split in two continues where the first part stopped
    split = KalmanFilter(Phi, C, Q, R, np.zeros(2), np.eye(2), Psi=Psi)
    split.filter(y[:30], u[:30])
    split.predict(u[29])
    second = split.filter(y[30:], u[30:])
    np.testing.assert_allclose(second.x_filtered, whole.x_filtered[30:], rtol=0, atol=1e-12)
    # prediction ahead uses the next transition matrices: Phi[k] ... Phi[k + steps - 1]
    ahead = KalmanFilter(Phi, C, Q, R, np.zeros(2), np.eye(2), Psi=Psi)
    ahead.update(y[0])
    xs, _ = ahead.predict_ahead(3, u[:3])
    x = ahead.x
    for i in range(3):
        x = Phi[i] @ x + Psi[i] @ u[i]
    np.testing.assert_allclose(xs[-1], x, rtol=0, atol=1e-14)


def test_short_or_misshapen_sequences_are_refused():
    Phi, C, Psi, u, y = _system()
    with pytest.raises(casest.OptionError, match="give Phi for every sample"):
        KalmanFilter(Phi[:10], C, Q, R, np.zeros(2), np.eye(2), Psi=Psi).filter(y, u)
    with pytest.raises(casest.OptionError, match="C must have shape"):
        KalmanFilter(Phi, C[:, :, :1], Q, R, np.zeros(2), np.eye(2))
    with pytest.raises(casest.OptionError, match="Phi must be a square matrix"):
        KalmanFilter(np.ones((3, 2, 3)), C, Q, R, np.zeros(2), np.eye(2))
