"""The filters' compiled passes over a record against the step-by-step filters and filterpy.

Truths: (1) the step-by-step EKF / IEKF of casest (a Python loop over :meth:`predict` and
:meth:`update`, NumPy algebra) on the README pendulum with 10 % of the measurements missing
at random and one sample with none, to 1e-12; (2) filterpy's ExtendedKalmanFilter, an
independent implementation of the measurement update, given the same Jacobians, the same
state prediction and the same discrete process noise, with the missing channels left out
of z, H and R, to 1e-12; (3) the NumPy RTS loop. Each compiled pass runs both ways: CasADi's
``mapaccum`` in its virtual machine (records shorter than ``jit_min_samples``) and the whole
record as one C loop (:class:`casest._casadi.record_loop.RecordLoop`, forced here by
``SolverSettings(jit=True)``; the test counts that the loop ran).
"""

import casadi as ca
import numpy as np
import pytest

import casest
from casest._casadi.numerics import compiler_available
from casest._casadi.record_loop import RecordLoop
from casest.backend.ipopt import SolverSettings
from casest.filters import compiled_passes, unscented
from casest.filters.ekf import ExtendedKalmanFilter, rts_smoother

filterpy_kalman = pytest.importorskip("filterpy.kalman")

FIELDS = ("x_predicted", "P_predicted", "x_filtered", "P_filtered", "transition", "innovation",
          "innovation_covariance", "iterations")
THETA, Q, R, P0 = {"c": 0.3, "L": 1.0}, {"rate": 0.5}, [0.05**2, 0.05**2], np.eye(2) * 1e-4


@pytest.fixture(params=["virtual machine", "C loop"], autouse=True)
def pass_kind(request, monkeypatch):
    """Run each test with the passes in CasADi's virtual machine and as one compiled C loop."""
    if request.param == "virtual machine":
        settings = lambda: SolverSettings(jit=False)
    else:
        if not compiler_available():
            pytest.skip("needs a C compiler")
        settings = lambda: SolverSettings(jit=True)
    for module in (compiled_passes, unscented):
        monkeypatch.setattr(module, "SolverSettings", settings)
    calls = []
    original = RecordLoop.__call__
    monkeypatch.setattr(RecordLoop, "__call__", lambda self, *a, **k: calls.append(1) or original(self, *a, **k))
    yield request.param
    assert bool(calls) == (request.param == "C loop")


def pendulum(input_hold: str = "zoh") -> casest.DynamicModel:
    ang, rate, torque, c, L = (ca.SX.sym(n) for n in ("ang", "rate", "torque", "c", "L"))
    P = casest.Parameter
    return casest.DynamicModel(
        [P("c", 0.0, 2.0, 0.3), P("L", 0.5, 2.0, 1.0)], [casest.State("ang", 1.0), casest.State("rate", 0.0)],
        ["torque"], rhs={"ang": rate, "rate": -9.81 / L * ca.sin(ang) - c * rate + torque},
        outputs={"px": L * ca.sin(ang), "py": -L * ca.cos(ang)}, substeps=4, input_hold=input_hold)


def gappy_record(model, N=300, seed=1) -> casest.Dataset:
    rng = np.random.default_rng(seed)
    t = np.arange(N) * 0.05
    torque = 0.5 * np.sin(1.3 * t)
    _, Y = model.simulate(THETA, model.dataset({"t": t, "torque": torque, "px": 0 * t, "py": 0 * t}))
    Y = Y + rng.normal(0.0, 0.05, Y.shape)
    Y[rng.random(Y.shape) < 0.1] = np.nan
    Y[5] = np.nan  # a sample with nothing measured: a pure prediction
    return model.dataset({"t": t, "torque": torque, "px": Y[:, 0], "py": Y[:, 1]}, missing="allow")


@pytest.mark.parametrize("iterated, input_hold", [(False, "zoh"), (True, "zoh"), (False, "cubic")])
def test_the_compiled_pass_equals_the_step_by_step_filter(iterated, input_hold):
    # zoh: the loop builds each sample's row from the record (RecordRows); cubic: from the rows of
    # record_columns (each interval's inputs from four samples)
    model = pendulum(input_hold)
    data = gappy_record(model)
    ekf = ExtendedKalmanFilter(model, THETA, Q, R, P0, iterated=iterated)
    loop, compiled = ekf.filter(data, compiled=False), ekf.filter(data, compiled=True)
    for name in FIELDS:
        a, b = getattr(loop, name), getattr(compiled, name)
        assert a.shape == b.shape, name
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=name)
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12, err_msg=name)
    assert compiled.log_likelihood == pytest.approx(loop.log_likelihood, rel=1e-12)
    assert compiled.iterations[5] == 0 and (not iterated or compiled.iterations.max() > 1)
    np.testing.assert_allclose(ekf.x, compiled.x_filtered[-1])  # the filter continues from the record's end


def test_the_compiled_pass_equals_filterpy():
    model = pendulum()
    data = gappy_record(model, seed=2)
    ekf = ExtendedKalmanFilter(model, THETA, Q, R, P0)
    ours = ekf.filter(data)
    theta = model.vector(THETA)
    Rm = np.diag(R)
    kf = filterpy_kalman.ExtendedKalmanFilter(dim_x=2, dim_z=2)
    kf.x, kf.P = np.array([1.0, 0.0]), P0.copy()
    t, U, Y = data.signals[:, 0], data.signals[:, 1:], data.outputs
    Ua, Ub = model.interval_input_values(U)
    for k in range(data.n_samples):
        np.testing.assert_allclose(kf.x, ours.x_predicted[k], rtol=1e-12, atol=1e-12)
        seen = np.isfinite(Y[k])

        def hx(x, seen=seen, u=U[k]):
            return np.asarray(ekf._measure(x, u, theta)[0]).reshape(-1)[seen]

        def jac(x, seen=seen, u=U[k]):
            return np.asarray(ekf._measure(x, u, theta)[1])[seen]

        kf.update(Y[k][seen] if seen.any() else None, jac, hx, R=Rm[np.ix_(seen, seen)])
        np.testing.assert_allclose(kf.x, ours.x_filtered[k], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(kf.P, ours.P_filtered[k], rtol=1e-12, atol=1e-14)
        if k < data.n_samples - 1:  # the same prediction: our step, its Jacobian and discrete Q
            x_next, P_next, Phi = (np.asarray(v) for v in ekf._propagate(
                kf.x, kf.P, Ua[k], Ub[k], t[k + 1] - t[k], theta, ekf.Qc, U[k], ekf.input_noise))
            kf.F, kf.Q = Phi, P_next - Phi @ kf.P @ Phi.T
            kf.predict_x = lambda u=0, x_next=x_next: setattr(kf, "x", x_next.reshape(-1))
            kf.predict()


def test_the_compiled_rts_pass_equals_the_numpy_loop():
    model = pendulum()
    result = ExtendedKalmanFilter(model, THETA, Q, R, P0).filter(gappy_record(model, N=700, seed=3))
    loop, compiled = rts_smoother(result, compiled=False), rts_smoother(result)
    np.testing.assert_allclose(compiled.x, loop.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(compiled.P, loop.P, rtol=1e-12, atol=1e-14)


def test_the_compiled_kalman_filter_equals_the_step_by_step_one():
    """The linear filter with an input, feed-through, a 3-state Gamma Q Gamma' and missing
    channels: the compiled pass against update/predict from Python (1e-12)."""
    rng = np.random.default_rng(4)
    A = rng.standard_normal((3, 3))
    Phi = 0.95 * A / np.max(np.abs(np.linalg.eigvals(A)))
    C, Psi, D, Gamma = rng.standard_normal((2, 3)), rng.standard_normal((3, 1)), rng.standard_normal((2, 1)), \
        rng.standard_normal((3, 2))
    Qw, Rv = np.diag([0.02, 0.05]), np.diag([0.1, 0.3])
    u = np.sin(0.1 * np.arange(400))[:, None]
    Y = rng.standard_normal((400, 2))
    Y[rng.random(Y.shape) < 0.15] = np.nan
    Y[7] = np.nan
    make = lambda: casest.KalmanFilter(Phi, C, Qw, Rv, [0.5, -0.2, 0.1], np.eye(3), Psi=Psi, D=D, Gamma=Gamma)
    loop_filter, compiled_filter = make(), make()
    loop, compiled = loop_filter.filter(Y, u, compiled=False), compiled_filter.filter(Y, u)
    for name in FIELDS:
        a, b = getattr(loop, name), getattr(compiled, name)
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=name)
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12, err_msg=name)
    assert compiled.log_likelihood == pytest.approx(loop.log_likelihood, rel=1e-12)
    np.testing.assert_allclose(compiled_filter.P, loop_filter.P, rtol=1e-12, atol=1e-14)


def test_the_compiled_unscented_pass_equals_the_step_by_step_filter():
    model = pendulum()
    data = gappy_record(model, seed=5)
    ukf = casest.UnscentedKalmanFilter(model, THETA, Q, R, P0)
    loop, compiled = ukf.filter(data, compiled=False), ukf.filter(data, compiled=True)
    for name in FIELDS:
        a, b = getattr(loop, name), getattr(compiled, name)
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=name)
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12, err_msg=name)
    assert compiled.log_likelihood == pytest.approx(loop.log_likelihood, rel=1e-12)



@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_a_pass_written_into_an_earlier_results_arrays_equals_a_fresh_one(kind, pass_kind):
    """filter(data, out=earlier): the pass over a second record of the same length equals a pass
    with fresh arrays (exactly: the same computation), and in the C loop it is written into the
    earlier result's arrays; a result of another length or of a pass step by step is refused."""
    model = pendulum()
    first, second = gappy_record(model, seed=6), gappy_record(model, seed=7)
    flt = (casest.UnscentedKalmanFilter if kind == "ukf" else ExtendedKalmanFilter)(model, THETA, Q, R, P0)
    earlier, fresh = flt.filter(first), flt.filter(second)
    reused = flt.filter(second, out=earlier)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(reused, name), getattr(fresh, name), err_msg=name)
    assert reused.log_likelihood == fresh.log_likelihood
    written_in_place = all(np.shares_memory(getattr(reused, name), getattr(earlier, name))
                           for name in ("x_predicted", "P_filtered", "innovation", "transition"))
    assert written_in_place == (pass_kind == "C loop")
    with pytest.raises(casest.OptionError, match="same length"):
        flt.filter(gappy_record(model, N=200), out=earlier)
    with pytest.raises(casest.OptionError, match="step by step"):
        flt.filter(second, out=flt.filter(second, compiled=False))


def test_a_filter_whose_options_change_runs_the_step_of_its_new_options():
    # the pass's step is kept per filter: changing iterated afterwards must give the IEKF's pass
    # (truth: a filter built iterated from the start)
    model = pendulum()
    data = gappy_record(model, seed=3)
    ekf = ExtendedKalmanFilter(model, THETA, Q, R, P0)
    plain = ekf.filter(data)
    ekf.iterated = True
    changed = ekf.filter(data)
    fresh = ExtendedKalmanFilter(model, THETA, Q, R, P0, iterated=True).filter(data)
    assert plain.iterations.max() == 1 and changed.iterations.max() > 1
    np.testing.assert_array_equal(changed.x_filtered, fresh.x_filtered)
    np.testing.assert_array_equal(changed.iterations, fresh.iterations)
