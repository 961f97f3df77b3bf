"""Delays on records as they come: time stamps that jitter about a uniform grid (as the AP2
record's do, +-0.13 ms at 50 Hz) and several manoeuvres (segments) in one estimate.
Truth: a first-order lag k / (T s + 1) simulated with the analytic input u(t - tau) at the
jittered time stamps (input delay) or with its output read at t - tau (output delay); the
estimates within 3 std of the truth."""

import casadi as ca
import numpy as np
import pytest

import casest

P = casest.Parameter
TRUTH = {"k": 2.0, "T": 0.5, "tau": 0.1}
DT = 0.02


def _model(delays):
    x, u, k, T = (ca.SX.sym(n) for n in ("x", "u", "k", "T"))
    return casest.DynamicModel([P("k", 0.1, 5.0, 1.0), P("T", 0.1, 3.0, 1.0), P("tau", 0.0, 0.2, 0.05)],
                               [casest.State("x", 0.0)], ["u"], rhs={"x": (k * u - x) / T}, outputs={"y": x},
                               delays=delays, sample_time=DT)


def _drive(t, phase=0.0):
    return np.sin(1.3 * t + phase) + 0.6 * np.sin(3.1 * t + 2 * phase) + 0.3 * np.sin(7.0 * t)


def _undelayed():
    x, u, k, T = (ca.SX.sym(n) for n in ("x", "u", "k", "T"))
    return casest.DynamicModel([P("k", 0.1, 5.0, 1.0), P("T", 0.1, 3.0, 1.0)], [casest.State("x", 0.0)], ["u"],
                               rhs={"x": (k * u - x) / T}, outputs={"y": x})


def _record(model, seed, n=600, jitter=1.3e-4, delayed="u", phase=0.0):
    """A record with jittered time stamps; the truth simulated with the analytic delayed input."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT + rng.uniform(-jitter, jitter, n) * (np.arange(n) > 0)
    truth, gains = _undelayed(), {"k": TRUTH["k"], "T": TRUTH["T"]}
    if delayed == "u":
        _, y = truth.simulate(gains, truth.dataset({"t": t, "u": _drive(np.maximum(t - TRUTH["tau"], 0.0), phase),
                                                         "y": 0 * t}))  # the input before the record: its first value
    else:  # the output at t - tau: simulate on a fine grid and read it there
        fine = np.arange(-0.5, t[-1] + DT, DT / 20)
        _, y_fine = truth.simulate(gains, truth.dataset({"t": fine, "u": _drive(fine, phase) * (fine >= 0),
                                                         "y": 0 * fine}))
        y = np.interp(t - TRUTH["tau"], fine, y_fine[:, 0])[:, None]
    noisy = y[:, 0] + 0.01 * rng.standard_normal(n)
    return model.dataset({"t": t, "u": _drive(t, phase) * (1 if delayed == "u" else (t >= 0)), "y": noisy})


def _within_3_std(est):
    for name, value in TRUTH.items():
        assert abs(est.values[name] - value) < 3 * est.stds[name], (name, est.values[name], est.stds[name])


def test_an_input_delay_on_a_jittered_record_is_recovered():
    model = _model({"u": "tau"})
    est = casest.estimate(model, _record(model, seed=1))
    assert est.success
    _within_3_std(est)


def test_an_output_delay_on_a_jittered_record_is_recovered():
    model = _model({"y": "tau"})
    est = casest.estimate(model, _record(model, seed=2, delayed="y"))
    assert est.success
    _within_3_std(est)


def test_time_stamps_far_off_the_grid_are_refused_with_the_fix():
    model = _model({"u": "tau"})
    record = _record(model, seed=3, jitter=0.004)
    with pytest.raises(casest.DataError, match=r"off the uniform grid, more than 5% of a sample.*mean interval"):
        casest.estimate(model, record)


@pytest.mark.parametrize("delayed", ["u", "y"])
def test_delays_with_two_segments(delayed):
    model = _model({delayed: "tau"})
    records = [_record(model, seed=10 + s, n=400, delayed=delayed, phase=float(s)) for s in range(2)]
    est = casest.estimate(model, records)
    assert est.success and len(est.experiments) == 2
    _within_3_std(est)


def test_output_delays_stop_at_the_segment_boundaries():
    """The stacked model's delayed outputs equal each segment's own (no value crosses a boundary)."""
    from casest.problem.experiments import stack_dynamic_experiments

    model = _model({"y": "tau"})
    records = [_record(model, seed=20 + s, n=150, delayed="y", phase=float(s)) for s in range(2)]
    stacked, data, _ = stack_dynamic_experiments(model, records, separate_noise=False)
    whole = stacked.predict_data(TRUTH, data)
    alone = np.concatenate([model.predict_data(TRUTH, r) for r in records])
    np.testing.assert_allclose(whole, alone, rtol=0, atol=1e-12)
