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


def _tables_or_functions(kind: str, n_outputs: int):
    """y_i = k_i0 f0(t - tau) + k_i1 f1(t - tau), i < n_outputs, with f0, f1 tables of a Gaussian
    bump and tanh (linear or B-spline) or those functions themselves."""
    grid = np.linspace(-6, 6, 241)
    if kind == "analytic":
        f0, f1 = (lambda v: ca.exp(-v**2)), ca.tanh
    else:
        f0 = ca.interpolant("f0", kind, [grid], np.exp(-grid**2))
        f1 = ca.interpolant("f1", kind, [grid], np.tanh(grid))
    t, tau = ca.SX.sym("t"), ca.SX.sym("tau")
    ks = {f"k{i}{j}": ca.SX.sym(f"k{i}{j}") for i in range(n_outputs) for j in range(2)}
    outputs = {f"y{i}": ks[f"k{i}0"] * f0(t - tau) + ks[f"k{i}1"] * f1(t - tau) for i in range(n_outputs)}
    params = [P("tau", 0.0, 1.0, 0.5)] + [P(name, -5.0, 5.0, 0.0) for name in ks]
    return casest.Model(params, ["t"], outputs, name=f"tables_{kind}_{n_outputs}")


@pytest.mark.parametrize("n_outputs", [1, 2, 3])
@pytest.mark.parametrize("kind", ["linear", "bspline"])
def test_parameters_multiplying_tables_are_linear_for_any_number_of_outputs(kind, n_outputs):
    """With two or more outputs every k was put in xi2 (the tables' zero-seed derivative terms);
    the partition now equals that of the same model written with the functions themselves.
    Truth: data simulated from the table model with fixed seeds, estimates within 3 std."""
    model = _tables_or_functions(kind, n_outputs)
    partition = casest.separate(model)
    analytic = casest.separate(_tables_or_functions("analytic", n_outputs))
    assert partition.linear == analytic.linear == tuple(n for n in model.parameter_names if n != "tau")
    assert partition.nonlinear == analytic.nonlinear == ("tau",)
    assert casest.separate(model, linear=list(partition.linear)).linear == partition.linear
    rng = np.random.default_rng(n_outputs)
    truth = np.concatenate([[0.3], rng.uniform(-2, 2, 2 * n_outputs)])
    t = np.linspace(-4, 4, 300)
    clean = model.predict(truth, t[:, None])
    data = casest.Dataset.from_arrays(model, t[:, None], clean + 0.01 * rng.standard_normal(clean.shape))
    est = casest.estimate(model, data)
    assert est.success and np.all(np.abs((est.theta - truth) / est.std) < 3)


@pytest.mark.parametrize("n_outputs", [1, 2])
def test_the_bulk_evaluator_without_lanes_returns_a_and_b(n_outputs):
    """A and b over all samples for a block of candidates, on the path a table's call takes (no
    SIMD form), equal the partition's own A and b evaluated sample by sample."""
    from casest.two_stage.sweep.evaluators import BulkEvaluator

    model = _tables_or_functions("linear", n_outputs)
    partition = casest.separate(model)
    t = np.linspace(-4, 4, 50)
    data = casest.Dataset.from_arrays(model, t[:, None], np.zeros((t.size, n_outputs)))
    bulk = BulkEvaluator(partition, data, 64.0, 3)
    xi2 = np.array([[0.1], [0.4], [0.7]])
    A, b = bulk(xi2)
    for m, tau in enumerate(xi2[:, 0]):
        for k, tk in enumerate(t):
            np.testing.assert_allclose(A[m, k * n_outputs:(k + 1) * n_outputs], np.asarray(partition.A([tk], [tau])),
                                       rtol=1e-13, atol=1e-15)
            np.testing.assert_allclose(b[m, k * n_outputs:(k + 1) * n_outputs],
                                       np.asarray(partition.b([tk], [tau])).reshape(-1), rtol=1e-13, atol=1e-15)


def test_a_table_with_a_gap_is_refused_by_its_position():
    """A NaN value would make every estimate near it NaN (truth: CasADi interpolates it)."""
    with pytest.raises(ModelError, match=r"values at flat positions \[1\].*not finite"):
        casest.lookup_table("cl", [[0.0, 1.0, 2.0]], [0.0, np.nan, 1.0])
