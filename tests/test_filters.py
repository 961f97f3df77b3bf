"""State estimation: Kalman filter and RTS smoother against filterpy; EKF/IEKF consistency.

Truths: (1) filterpy's KalmanFilter (batch_filter with update_first, rts_smoother), an
independent implementation of the same equations, to 1e-10; (2) simulated records of a
pendulum with process noise (50 substeps per sample: RK4 of the drift plus the noise
increment, fixed seeds):
the normalised estimation error squared (NEES) averaged over a Monte-Carlo batch lies in
its chi-square 95 % band at >= 88 % of the samples (95 % expected; the band is for each
sample, the samples are correlated).
"""

import casadi as ca
import numpy as np
import pytest
from scipy import stats

import casest
from casest.filters.ekf import ExtendedKalmanFilter, KalmanFilter, rts_smoother

filterpy_kalman = pytest.importorskip("filterpy.kalman")


def linear_system(seed=0):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((3, 3))
    Phi = 0.95 * A / np.max(np.abs(np.linalg.eigvals(A)))  # stable
    C = rng.standard_normal((2, 3))
    Psi = rng.standard_normal((3, 1))
    Q = np.diag([0.02, 0.05, 0.01])
    R = np.diag([0.1, 0.3])
    return Phi, C, Psi, Q, R


def linear_record(Phi, C, Psi, Q, R, N, seed, with_input=True):
    rng = np.random.default_rng(seed)
    u = np.sin(0.1 * np.arange(N))[:, None] if with_input else np.zeros((N, 1))
    x = np.zeros(3)
    Y = []
    for k in range(N):
        Y.append(C @ x + rng.multivariate_normal(np.zeros(2), R))
        x = Phi @ x + Psi @ u[k] + rng.multivariate_normal(np.zeros(3), Q)
    return np.array(Y), u


def filterpy_filter(Phi, C, Psi, Q, R, x0, P0):
    kf = filterpy_kalman.KalmanFilter(dim_x=3, dim_z=2, dim_u=1)
    kf.F, kf.H, kf.B, kf.Q, kf.R = Phi.copy(), C.copy(), Psi.copy(), Q.copy(), R.copy()
    kf.x, kf.P = x0.reshape(3, 1).copy(), P0.copy()
    return kf


def test_kalman_filter_equals_filterpy():
    Phi, C, Psi, Q, R = linear_system()
    Y, u = linear_record(Phi, C, Psi, Q, R, 300, seed=1)
    x0, P0 = np.array([0.5, -0.2, 0.1]), np.eye(3)
    ours = KalmanFilter(Phi, C, Q, R, x0, P0, Psi=Psi).filter(Y, u)
    kf = filterpy_filter(Phi, C, Psi, Q, R, x0, P0)
    means, covs, means_p, covs_p = kf.batch_filter([y[:, None] for y in Y], us=[v[:, None] for v in u], update_first=True)
    np.testing.assert_allclose(ours.x_filtered, means[:, :, 0], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ours.P_filtered, covs, rtol=1e-10, atol=1e-12)
    # filterpy's means_p[k] is the prediction made after sample k: ours at k + 1
    np.testing.assert_allclose(ours.x_predicted[1:], means_p[:-1, :, 0], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ours.P_predicted[1:], covs_p[:-1], rtol=1e-10, atol=1e-12)


def test_rts_smoother_equals_filterpy():
    # filterpy's smoother predicts with F x alone (no B u): compared on a record without input
    Phi, C, Psi, Q, R = linear_system(2)
    Y, u = linear_record(Phi, C, Psi, Q, R, 300, seed=3, with_input=False)
    x0, P0 = np.zeros(3), 2.0 * np.eye(3)
    result = KalmanFilter(Phi, C, Q, R, x0, P0).filter(Y)
    smooth = rts_smoother(result)
    kf = filterpy_filter(Phi, C, Psi, Q, R, x0, P0)
    means, covs, _, _ = kf.batch_filter([y[:, None] for y in Y], update_first=True)
    xs, Ps, _, _ = kf.rts_smoother(means, covs, Fs=[Phi] * len(Y), Qs=[Q] * len(Y))
    np.testing.assert_allclose(smooth.x, xs[:, :, 0], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(smooth.P, Ps, rtol=1e-10, atol=1e-12)
    # the smoother never does worse than the filter: its covariance is smaller
    assert np.all(np.trace(smooth.P, axis1=1, axis2=2) <= np.trace(result.P_filtered, axis1=1, axis2=2) + 1e-12)


def test_missing_channels_are_skipped_not_propagated():
    Phi, C, Psi, Q, R = linear_system(4)
    Y, u = linear_record(Phi, C, Psi, Q, R, 100, seed=5)
    Y[10, 0] = np.nan  # one channel missing
    Y[20] = np.nan  # both missing: a pure prediction
    x0, P0 = np.zeros(3), np.eye(3)
    ours = KalmanFilter(Phi, C, Q, R, x0, P0, Psi=Psi).filter(Y, u)
    assert np.all(np.isfinite(ours.x_filtered)) and np.all(np.isfinite(ours.P_filtered))
    np.testing.assert_array_equal(ours.x_filtered[20], ours.x_predicted[20])
    assert ours.iterations[20] == 0
    # sample 10 by filterpy with only the measured channel's rows of H and R
    kf = filterpy_filter(Phi, C, Psi, Q, R, ours.x_predicted[10], ours.P_predicted[10])
    kf.update(Y[10, 1:, None], R=R[1:, 1:], H=C[1:])
    np.testing.assert_allclose(ours.x_filtered[10], kf.x[:, 0], rtol=1e-10)
    np.testing.assert_allclose(ours.P_filtered[10], kf.P, rtol=1e-10)


def test_prediction_ahead_grows_the_covariance():
    Phi, C, Psi, Q, R = linear_system(6)
    kf = KalmanFilter(Phi, C, Q, R, np.ones(3), 0.1 * np.eye(3), Psi=Psi)
    xs, Ps = kf.predict_ahead(5, u=[0.3])
    x, P = np.ones(3), 0.1 * np.eye(3)
    for i in range(5):  # Eq. 2.12-2.13 written out
        x, P = Phi @ x + Psi[:, 0] * 0.3, Phi @ P @ Phi.T + Q
        np.testing.assert_allclose(xs[i], x, rtol=1e-12)
        np.testing.assert_allclose(Ps[i], P, rtol=1e-12)
    np.testing.assert_array_equal(kf.x, np.ones(3))  # the filter's own state is untouched


# ----------------------------------------------------------------------------- EKF / IEKF
G_OVER_L, LENGTH, DAMPING, Q_RATE, DT = 9.81, 1.0, 0.3, 0.5, 0.05
R_PENDULUM = np.array([0.05, 0.05]) ** 2


def pendulum() -> casest.DynamicModel:
    """ang'' = -(g/L) sin(ang) - c ang' + u + w; measured: the bob's position (L sin, -L cos)."""
    ang, rate, u, c, L = (ca.SX.sym(n) for n in ("ang", "rate", "u", "c", "L"))
    P = casest.Parameter
    return casest.DynamicModel(
        [P("c", 0.0, 2.0, 0.3), P("L", 0.5, 2.0, 1.0)], [casest.State("ang", 0.0), casest.State("rate", 0.0)], ["u"],
        {"ang": rate, "rate": -G_OVER_L / L * ca.sin(ang) - c * rate + u},
        {"px": L * ca.sin(ang), "py": -L * ca.cos(ang)}, name="pendulum", substeps=4, input_hold="zoh")


def _rk4(f, x, h):
    k1 = f(x)
    k2 = f(x + 0.5 * h * k1)
    k3 = f(x + 0.5 * h * k2)
    k4 = f(x + h * k3)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def pendulum_record(model, seed, N=200, x0=(1.0, 0.0)):
    """The truth with process noise on the rate: per 1 ms substep an RK4 step of the drift plus
    the noise increment (additive noise: no Euler phase error, which would bias L by 0.3 %)."""
    rng = np.random.default_rng([seed, 11])
    t = np.arange(N) * DT
    u = 0.5 * np.sin(1.3 * t)
    x = np.array(x0, dtype=float)
    states, m = [], 50
    h = DT / m
    for k in range(N):
        states.append(x.copy())

        def drift(s, k=k):
            return np.array([s[1], -G_OVER_L / LENGTH * np.sin(s[0]) - DAMPING * s[1] + u[k]])

        for _ in range(m):
            x = _rk4(drift, x, h) + np.array([0.0, np.sqrt(Q_RATE * h) * rng.standard_normal()])
    X = np.array(states)
    Y = np.column_stack([LENGTH * np.sin(X[:, 0]), -LENGTH * np.cos(X[:, 0])])
    Y = Y + rng.standard_normal(Y.shape) * np.sqrt(R_PENDULUM)
    return model.dataset({"t": t, "u": u, "px": Y[:, 0], "py": Y[:, 1]}), X


@pytest.mark.parametrize("iterated", [False, True])
def test_ekf_is_consistent_by_nees(iterated):
    model = pendulum()
    runs, N, n = 40, 200, 2
    P0 = np.diag([0.1, 0.1]) ** 2
    nees = np.zeros(N)
    for seed in range(runs):
        rng = np.random.default_rng([seed, 12])
        start = np.array([1.0, 0.0]) + rng.standard_normal(2) * np.sqrt(np.diag(P0))  # truth drawn from the prior
        data, X = pendulum_record(model, seed, N, x0=start)
        ekf = ExtendedKalmanFilter(model, {"c": DAMPING, "L": LENGTH}, {"rate": Q_RATE}, R_PENDULUM, P0,
                                   x0=[1.0, 0.0], iterated=iterated)
        result = ekf.filter(data)
        nees += result.nees(X)
    mean_nees = nees / runs
    lo, hi = stats.chi2.ppf([0.025, 0.975], runs * n) / runs
    inside = np.mean((mean_nees >= lo) & (mean_nees <= hi))
    assert inside >= 0.88, (inside, mean_nees.mean())


def test_ekf_smoother_and_missing_channels():
    model = pendulum()
    data, X = pendulum_record(model, 99)
    px = data.outputs[:, 0].copy()
    px[::3] = np.nan
    gappy = model.dataset({"t": data.signals[:, 0], "u": data.signals[:, 1], "px": px, "py": data.outputs[:, 1]},
                          missing="allow")
    ekf = ExtendedKalmanFilter(model, {"c": DAMPING, "L": LENGTH}, {"rate": Q_RATE}, R_PENDULUM, np.diag([0.01, 0.01]),
                               x0=X[0])
    result, smooth = ekf.smooth(gappy)
    assert np.all(np.isfinite(result.x_filtered)) and np.all(np.isfinite(smooth.x))
    assert np.all(np.isnan(result.innovation[::3, 0])) and np.all(np.isfinite(result.innovation[:, 1]))
    # smoothing uses the future: smaller errors than filtering on the angle rate
    err_f = np.sqrt(np.mean((result.x_filtered[:, 1] - X[:, 1]) ** 2))
    err_s = np.sqrt(np.mean((smooth.x[:, 1] - X[:, 1]) ** 2))
    assert err_s < err_f
    assert np.all(np.abs(smooth.x - X) < 4 * smooth.std)


# ----------------------------------------------------------------------------- filter-error ML
LOOP_TRUTH = {"a": 0.4, "k": 4.0, "b": 1.0}
LOOP_Q, LOOP_FEEDBACK, LOOP_DT = 0.5, 2.0, 0.02
LOOP_NOISE = np.array([0.01, 0.02])


def loop_model() -> casest.DynamicModel:
    """x'' = -k x - a x' + b u + w: an oscillator whose input feeds back the measured rate."""
    x, v, u, a, k, b = (ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "b"))
    P = casest.Parameter
    return casest.DynamicModel([P("a", 0.0, 3.0, 1.0), P("k", 0.5, 10.0, 2.0), P("b", 0.1, 5.0, 1.5)],
                               [casest.State("x", 0.0), casest.State("v", 0.0)], ["u"],
                               {"x": v, "v": -k * x - a * v + b * u}, {"y1": x, "y2": v}, name="oscillator_loop",
                               substeps=2, input_hold="zoh")


def loop_record(model, seed, N=1000):
    """Closed loop u = r - K y2 (held over the sample), process noise on v (RK4 drift plus the
    noise increment per substep, 50 substeps)."""
    rng = np.random.default_rng([seed, 21])
    t = np.arange(N) * LOOP_DT
    ref = np.sin(0.9 * t) + 0.6 * np.sin(2.7 * t + 1) + 0.4 * np.sin(5.1 * t + 2)
    s, U, Y, sub = np.zeros(2), [], [], 50
    h = LOOP_DT / sub
    for k in range(N):
        y = s + LOOP_NOISE * rng.standard_normal(2)
        Y.append(y)
        U.append(ref[k] - LOOP_FEEDBACK * y[1])
        def drift(x, u=U[-1]):
            return np.array([x[1], -LOOP_TRUTH["k"] * x[0] - LOOP_TRUTH["a"] * x[1] + LOOP_TRUTH["b"] * u])

        for _ in range(sub):
            s = _rk4(drift, s, h) + np.array([0.0, np.sqrt(LOOP_Q * h) * rng.standard_normal()])
    Y = np.array(Y)
    return model.dataset({"t": t, "u": np.array(U), "y1": Y[:, 0], "y2": Y[:, 1]})


def test_filter_error_cost_is_the_filters_likelihood():
    # truth: the numeric EKF's log-likelihood, -V - (measured samples)/2 ln(2 pi), to 1e-10
    from casest.filter_error.estimator import filter_error_cost

    model = pendulum()
    data, X = pendulum_record(model, 5, 150)
    py = data.outputs[:, 1].copy()
    py[::4] = np.nan
    data = model.dataset({"t": data.signals[:, 0], "u": data.signals[:, 1], "px": data.outputs[:, 0], "py": py},
                         missing="allow")
    theta, q, P0 = {"c": 0.5, "L": 1.1}, {"rate": 0.8}, np.diag([1.0, 0.5])
    ekf = ExtendedKalmanFilter(model, theta, q, R_PENDULUM * 2, P0).filter(data)
    V = filter_error_cost(model, data, theta, q, R_PENDULUM * 2, P0=P0)
    n_measured = np.isfinite(data.outputs).sum()
    np.testing.assert_allclose(V, -ekf.log_likelihood - 0.5 * n_measured * np.log(2 * np.pi), rtol=1e-10)


def test_filter_error_recovers_parameters_and_process_noise_where_output_error_is_biased():
    model = loop_model()
    data = loop_record(model, 0)
    truth = model.vector(LOOP_TRUTH)
    fe = casest.filter_error_estimate(model, data, {"v": 0.1})
    assert fe.success, fe.notes
    assert np.all(np.abs(fe.theta - truth) < 3 * fe.std), (fe.theta - truth) / fe.std
    assert abs(fe.process_noise["v"] - LOOP_Q) < 3 * fe.process_noise_std["v"]
    assert np.all(np.abs(fe.R - LOOP_NOISE**2) < 3 * fe.R_std)
    # output error on the same record: the stiffness is off by many of its own std and by > 20 %
    oe = casest.estimate(model, data)
    k = model.parameter_names.index("k")
    assert abs(oe.theta[k] - truth[k]) > 10 * oe.std[k] and abs(oe.theta[k] / truth[k] - 1) > 0.2
