"""Input time delays as estimated parameters (fractional, by interpolation between samples).

Truth: the oscillator of test_dynamic driven by a multisine delayed by 0.13 s (6.5 samples),
the delayed input computed analytically (not by the interpolation under test), white noise
with a fixed seed; the estimate is within 3 std of every true value.
"""

import casadi as ca
import numpy as np
import pytest

import casest
from casest.errors import ModelError

TAU, DT, N = 0.13, 0.02, 1500
TRUTH = {"a": 0.3, "k": 3.0, "c": 1.7, "d": -0.4, "tau": TAU}


def multisine(t):
    return np.sin(0.7 * t) + 0.5 * np.sin(2.3 * t) + 0.3 * np.cos(4.1 * t)


def delayed_oscillator(**options) -> casest.DynamicModel:
    x, v, u, a, k, c, d = (ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "c", "d"))
    P = casest.Parameter
    return casest.DynamicModel(
        [P("a", 0.05, 2.0, 0.5), P("k", 0.5, 8.0, 2.0), P("c", -5.0, 5.0, 1.0), P("d", -5.0, 5.0, 0.0),
         P("tau", 0.0, 0.3, 0.05, unit="s")],
        [casest.State("x", 0.0), casest.State("v", 0.0)], ["u"], {"x": v, "v": -k * x - a * v + u},
        {"y1": c * x + d, "y2": v}, name="delayed_oscillator", **options)


def delayed_record(seed: int) -> casest.Dataset:
    """Outputs of the oscillator driven by u(t - TAU) (exact), noise 0.05 and 0.02; the data carry u(t)."""
    t = np.arange(N) * DT
    plain = casest.DynamicModel(
        [casest.Parameter(n, -10, 10, 0) for n in ("a", "k", "c", "d")], [casest.State("x", 0.0), casest.State("v", 0.0)],
        ["u"], {"x": ca.SX.sym("v"), "v": -ca.SX.sym("k") * ca.SX.sym("x") - ca.SX.sym("a") * ca.SX.sym("v")
                + ca.SX.sym("u")}, {"y1": ca.SX.sym("c") * ca.SX.sym("x") + ca.SX.sym("d"), "y2": ca.SX.sym("v")},
        substeps=8)
    zeros = np.zeros(N)
    # before the record the input is unknown: the model holds its first value, and so does the truth
    shifted = plain.dataset({"t": t, "u": multisine(np.maximum(t - TAU, 0.0)), "y1": zeros, "y2": zeros})
    _, clean = plain.simulate({k: TRUTH[k] for k in ("a", "k", "c", "d")}, shifted)
    z = clean + np.random.default_rng([seed, 13]).standard_normal(clean.shape) * [0.05, 0.02]
    model = delayed_oscillator(delays={"u": "tau"}, sample_time=DT)
    return model.dataset({"t": t, "u": multisine(t), "y1": z[:, 0], "y2": z[:, 1]})


def test_a_delay_of_013_s_is_recovered_within_three_std():
    model = delayed_oscillator(delays={"u": "tau"}, sample_time=DT)
    data = delayed_record(0)
    est = casest.estimate(model, data)
    assert est.success, est.notes
    truth = model.vector(TRUTH)
    z = (est.theta - truth) / est.std
    assert np.all(np.abs(z) < 3), dict(zip(model.parameter_names, z))
    i = model.parameter_names.index("tau")
    assert est.std[i] < 0.02  # resolved to well under a sample


def test_lagged_columns_are_derived_from_the_input():
    model = delayed_oscillator(delays={"u": "tau"}, sample_time=DT)
    lags = [s.name for s in model.inputs if "@" in s.name]
    assert lags == ["u@lead"] + [f"u@{j}" for j in range(1, 18)]  # the next sample; ceil(0.3 / 0.02) + 2 = 17
    u = np.arange(20.0)
    data = model.dataset({"t": np.arange(20) * DT, "u": u, "y1": np.zeros(20), "y2": np.zeros(20)})
    np.testing.assert_array_equal(data.column("u@3"), np.concatenate([[0.0] * 3, u[:-3]]))
    np.testing.assert_array_equal(data.column("u@lead"), np.concatenate([u[1:], [19.0]]))


@pytest.mark.parametrize("tau", [0.0, 0.005, 0.01, 0.015, 0.02, 0.13])
def test_the_interpolation_weights_sum_to_one_at_any_delay(tau):
    """A constant input stays constant when delayed, also under one sample (which needs the next
    sample: without it the weights at half a sample sum to 1.0625)."""
    u, tau_s = ca.SX.sym("u"), ca.SX.sym("tau")
    model = casest.DynamicModel([casest.Parameter("tau", 0.0, 0.3, 0.05)], [casest.State("x", 0.0)], ["u"],
                                {"x": -ca.SX.sym("x") + 0 * tau_s}, {"y": u}, delays={"u": "tau"}, sample_time=DT)
    n = 30
    data = model.dataset({"t": np.arange(n) * DT, "u": np.full(n, 2.5), "y": np.zeros(n)})
    np.testing.assert_allclose(model.predict_data([tau], data)[:, 0], 2.5, rtol=1e-14)


def test_delay_options_are_checked():
    with pytest.raises(ModelError, match="sample_time"):
        delayed_oscillator(delays={"u": "tau"})
    with pytest.raises(ModelError, match="not an input"):
        delayed_oscillator(delays={"w": "tau"}, sample_time=DT)
    with pytest.raises(ModelError, match="not declared"):
        delayed_oscillator(delays={"u": "lag"}, sample_time=DT)
