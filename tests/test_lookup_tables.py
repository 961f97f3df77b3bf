"""Lookup tables (casadi.interpolant) in models: accepted in static outputs and in a dynamic
model's right-hand side, estimated like any other expression; an integrator inside an output
is refused with a message that names it.

Truth: data simulated from the same model and table at stated parameter values, white noise
with fixed seeds; estimates within 3 std of the truth.
"""

import casadi as ca
import numpy as np
import pytest

import casest
from casest.errors import ModelError

P = casest.Parameter
GRID = np.linspace(-0.5, 0.5, 41)
LIFT = 2 * np.pi * GRID / (1 + 4 * GRID**2)  # a lift curve that bends


@pytest.mark.parametrize("method", ["bspline", "linear"])
def test_a_lookup_table_in_a_static_output(method):
    CL = ca.interpolant("CL", method, [GRID], LIFT)
    alpha, k, b, c = (ca.SX.sym(n) for n in ("alpha", "k", "b", "c"))
    model = casest.Model([P("k", 0.5, 2.0, 1.0), P("b", -0.1, 0.1, 0.0), P("c", nominal=0.0)], ["alpha"],
                         {"CLm": k * CL(alpha + b) + c}, name=f"lookup_{method}")
    part = casest.separate(model)
    assert part.linear == ("k", "c") and part.nonlinear == ("b",)  # the table's argument is swept
    truth = {"k": 1.2, "b": 0.03, "c": -0.05}
    rng = np.random.default_rng(0)
    a = rng.uniform(-0.4, 0.4, 2000)
    clean = np.asarray(model.predict(model.vector(truth), a[:, None])).reshape(-1)
    data = casest.Dataset.from_arrays(model, a[:, None], (clean + 0.01 * rng.standard_normal(a.size))[:, None])
    est = casest.estimate(model, data)
    assert est.success, est.notes
    assert np.all(np.abs((est.theta - model.vector(truth)) / est.std) < 3)


def test_a_lookup_table_in_a_dynamic_right_hand_side():
    grid = np.linspace(-2, 2, 21)
    T = ca.interpolant("T", "bspline", [grid], np.tanh(grid) + 0.1 * grid)
    x, u, a, k = (ca.SX.sym(n) for n in ("x", "u", "a", "k"))
    model = casest.DynamicModel([P("a", 0.1, 5.0, 1.0), P("k", 0.1, 5.0, 1.0)], [casest.State("x", 0.0)], ["u"],
                                {"x": -a * x + k * T(u)}, {"y": x}, name="lookup_dynamic")
    t = np.arange(1000) * 0.02
    uu = 1.5 * np.sin(0.7 * t) + 0.5 * np.sin(2.9 * t)
    truth = {"a": 1.3, "k": 2.1}
    _, y = model.simulate(truth, model.dataset({"t": t, "u": uu, "y": 0 * t}))
    y = y[:, 0] + 0.01 * np.random.default_rng(1).standard_normal(t.size)
    est = casest.estimate(model, model.dataset({"t": t, "u": uu, "y": y}))
    assert est.success, est.notes
    assert np.all(np.abs((est.theta - model.vector(truth)) / est.std) < 3)


def test_an_integrator_inside_an_output_is_refused_by_name():
    xs, p = ca.MX.sym("xs"), ca.MX.sym("p")
    flow = ca.integrator("decay", "cvodes", {"x": xs, "p": p, "ode": -p * xs}, 0, 1)
    x0, rate = ca.SX.sym("x0"), ca.SX.sym("rate")
    with pytest.raises(ModelError, match="'decay'.*casest.DynamicModel"):
        casest.Model([P("rate", 0.1, 2.0, 1.0)], ["x0"], {"y": flow(x0=x0, p=rate)["xf"]})
