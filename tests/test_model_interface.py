"""Features that cross the static/dynamic border: fixed parameters, the embedding API.

Truths: a DynamicModel with a parameter held equals the same model written by hand with
the value in its equations (estimates to 1e-8); the embedding API's optimum of a dynamic
problem equals ``casest.estimate``'s (same ML cost, paper Eq. 6, to 1e-8 relative).
"""

import casadi as ca
import numpy as np
import pytest

import casest

TRUTH = {"a": 0.3, "k": 3.0, "c": 1.7, "d": -0.4, "x0": 0.6}
NOISE = np.array([0.05, 0.02])


def oscillator(held: dict | None = None) -> casest.DynamicModel:
    """x'' = -k x - a x' + u, x(0) = x0; y1 = c x + d, y2 = x'. ``held``: written in as numbers."""
    held = held or {}
    s = {n: ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "c", "d", "x0")}
    value = {n: held.get(n, s[n]) for n in ("a", "k", "c", "d")}
    P = casest.Parameter
    params = [P("a", 0.05, 2.0, 0.5), P("k", 0.5, 8.0, 2.0), P("c", -5.0, 5.0, 1.0), P("d", -5.0, 5.0, 0.0),
              P("x0", -2.0, 2.0, 0.0)]
    return casest.DynamicModel(
        [p for p in params if p.name not in held],
        [casest.State("x", held.get("x0", "x0")), casest.State("v", 0.0)], ["u"],
        {"x": s["v"], "v": -value["k"] * s["x"] - value["a"] * s["v"] + s["u"]},
        {"y1": value["c"] * s["x"] + value["d"], "y2": s["v"]}, name="oscillator", substeps=2)


@pytest.fixture(scope="module")
def record():
    model = oscillator()
    t = np.arange(600) * 0.02
    u = np.sin(0.7 * t) + 0.5 * np.sin(2.3 * t)
    zeros = np.zeros_like(t)
    _, clean = model.simulate(TRUTH, model.dataset({"t": t, "u": u, "y1": zeros, "y2": zeros}))
    z = clean + np.random.default_rng(11).standard_normal(clean.shape) * NOISE
    return model, model.dataset({"t": t, "u": u, "y1": z[:, 0], "y2": z[:, 1]})


@pytest.mark.parametrize("held", [{"d": -0.4}, {"k": 3.0, "x0": 0.6}])
def test_dynamic_model_with_fixed_parameters_equals_the_model_written_with_the_values(record, held):
    model, data = record
    by_hand = oscillator(held)
    reference = casest.estimate(by_hand, by_hand.dataset({n: data.column(n) for n in ("t", "u", "y1", "y2")}))
    est = casest.estimate(model, data, fixed=held)
    assert est.success and reference.success
    for name in by_hand.parameter_names:
        np.testing.assert_allclose(est.values[name], reference.values[name], rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(est.stds[name], reference.stds[name], rtol=1e-6)
    for name, value in held.items():
        assert est.values[name] == value and est.stds[name] is None
    assert est.fixed_parameters == tuple(held)
    np.testing.assert_allclose(est.cost, reference.cost, rtol=1e-10)
