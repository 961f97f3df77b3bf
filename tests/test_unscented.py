"""The unscented Kalman filter (casest.UnscentedKalmanFilter) against filterpy and itself.

Truths: (1) filterpy's UnscentedKalmanFilter with MerweScaledSigmaPoints of the same alpha,
beta, kappa, the pendulum's RK4 written in NumPy here (four substeps, the torque held), the
same discrete Q = Q_c dt and the missing channels left out of z, hx and R, to 1e-10; (2) the
step-by-step filter (Python loop over predict and update) against the compiled pass, to 1e-12;
(3) on a linear model the unscented transform is exact: the UKF equals the Kalman filter run
with the same discrete matrices.
"""

import numpy as np
import pytest

import casest
from casest.errors import OptionError
from test_compiled_filters import FIELDS, P0, Q, R, THETA, gappy_record, pendulum

filterpy_kalman = pytest.importorskip("filterpy.kalman")


def _rk4(x, torque, dt, c=THETA["c"], L=THETA["L"], substeps=4):
    def f(s):
        return np.array([s[1], -9.81 / L * np.sin(s[0]) - c * s[1] + torque])

    h = dt / substeps
    for _ in range(substeps):
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def test_the_unscented_filter_equals_filterpy():
    model = pendulum()
    data = gappy_record(model, seed=2)
    alpha, beta, kappa = 0.5, 2.0, 1.0
    ours = casest.UnscentedKalmanFilter(model, THETA, Q, R, P0, alpha=alpha, beta=beta, kappa=kappa).filter(data)
    t, U, Y = data.signals[:, 0], data.signals[:, 1:], data.outputs
    dt = t[1] - t[0]
    points = filterpy_kalman.MerweScaledSigmaPoints(2, alpha=alpha, beta=beta, kappa=kappa)
    ukf = filterpy_kalman.UnscentedKalmanFilter(dim_x=2, dim_z=2, dt=dt, hx=None, fx=None, points=points)
    ukf.x, ukf.P = np.array([1.0, 0.0]), P0.copy()
    ukf.Q = np.diag([0.0, Q["rate"]]) * dt
    ukf.sigmas_f = points.sigma_points(ukf.x, ukf.P)  # filterpy draws them in predict, which the first sample lacks
    Rm = np.diag(R)
    L = THETA["L"]
    for k in range(data.n_samples):
        np.testing.assert_allclose(ukf.x, ours.x_predicted[k], rtol=1e-10, atol=1e-12)
        seen = np.isfinite(Y[k])
        if seen.any():
            ukf.update(Y[k][seen], R=Rm[np.ix_(seen, seen)],
                       hx=lambda x, seen=seen: np.array([L * np.sin(x[0]), -L * np.cos(x[0])])[seen])
        np.testing.assert_allclose(ukf.x, ours.x_filtered[k], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(ukf.P, ours.P_filtered[k], rtol=1e-10, atol=1e-14)
        if k < data.n_samples - 1:
            ukf.predict(dt=dt, fx=lambda x, dt, u=U[k, 0]: _rk4(x, u, dt))


def test_the_compiled_pass_equals_the_step_by_step_filter():
    model = pendulum()
    data = gappy_record(model)
    ukf = casest.UnscentedKalmanFilter(model, THETA, Q, R, P0)
    loop, compiled = ukf.filter(data, compiled=False), ukf.filter(data, compiled=True)
    for name in FIELDS:
        a, b = getattr(loop, name), getattr(compiled, name)
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=name)
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12, err_msg=name)
    assert compiled.log_likelihood == pytest.approx(loop.log_likelihood, rel=1e-12)


def test_on_a_linear_model_the_unscented_filter_is_the_kalman_filter():
    """x' = A x + B u, y = C x: sigma points carry means and covariances exactly through linear maps."""
    import casadi as ca

    x1, x2, u = ca.SX.sym("x1"), ca.SX.sym("x2"), ca.SX.sym("u")
    a = ca.SX.sym("a")
    model = casest.DynamicModel([casest.Parameter("a", 0.1, 5.0, 1.0)], [casest.State("x1", 0.0), casest.State("x2", 0.0)],
                                ["u"], rhs={"x1": x2, "x2": -a * x1 - 0.4 * x2 + u}, outputs={"y": x1 + 0.5 * x2},
                                input_hold="zoh")
    rng = np.random.default_rng(5)
    t = np.arange(200) * 0.1
    uu = np.sign(np.sin(0.7 * t))
    y = rng.normal(0.0, 0.1, t.size)
    data = model.dataset({"t": t, "u": uu, "y": y})
    ukf = casest.UnscentedKalmanFilter(model, {"a": 2.0}, {"x2": 0.3}, [0.01], np.eye(2) * 0.1, x0=[0.0, 0.0],
                                       alpha=1.0, kappa=1.0).filter(data)
    step = model.step_function
    x, P = np.zeros(2), np.eye(2) * 0.1
    C = np.array([[1.0, 0.5]])
    for k in range(t.size):
        S = C @ P @ C.T + 0.01
        K = P @ C.T / S
        x = x + (K * (y[k] - C @ x)).reshape(-1)
        P = P - K @ S @ K.T
        np.testing.assert_allclose(ukf.x_filtered[k], x, rtol=1e-9, atol=1e-12)
        if k < t.size - 1:
            def moved(v, k=k):
                return np.asarray(step(v, [uu[k]], [uu[k]], 0.1, [2.0])).reshape(-1)

            x_next = moved(x)  # the affine step: its matrix from the images of x + e_i
            Phi = np.column_stack([moved(x + e) - x_next for e in np.eye(2)])
            x, P = x_next, Phi @ P @ Phi.T + np.diag([0.0, 0.3]) * 0.1


def test_bad_settings_are_named():
    model = pendulum()
    with pytest.raises(OptionError, match="0 < alpha <= 1"):
        casest.UnscentedKalmanFilter(model, THETA, Q, R, P0, alpha=0.0)
    with pytest.raises(OptionError, match="needs a casest.DynamicModel"):
        casest.UnscentedKalmanFilter(casest.load_model_file("scalar2").model(), {}, {}, [1.0], [1.0])
    with pytest.raises(OptionError, match="R must have shape"):
        casest.UnscentedKalmanFilter(model, THETA, Q, [0.1, 0.1, 0.1], P0)
