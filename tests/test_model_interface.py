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


@pytest.fixture(scope="module")
def reference(record):
    model, data = record
    est = casest.estimate(model, data)
    assert est.success
    return est


def test_add_to_opti_with_a_dynamic_model_reaches_the_estimate(record, reference):
    from casest.embed import add_to_opti

    model, data = record
    opti = ca.Opti()
    est = add_to_opti(opti, model, data, start="stage1")
    est.minimize()
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes"})
    theta, R = est.values(opti.solve())
    problem = casest.Problem(model, data)
    np.testing.assert_allclose(problem.cost(theta, R), reference.cost, rtol=1e-8)
    np.testing.assert_allclose(theta, reference.theta, rtol=1e-5, atol=1e-7)
    unc = est.standard_deviations(opti.debug)
    np.testing.assert_allclose(unc.std, reference.std, rtol=1e-4)


def test_ml_problem_of_a_dynamic_model_reaches_the_estimate(record, reference):
    from casest.embed import ml_problem

    model, data = record
    ml = ml_problem(casest.Problem(model, data))
    solver = ml.solver()
    lbx, ubx = ml.bounds()
    sol = solver(x0=ml.x0(reference.theta * 1.02, reference.R * 1.5), p=ml.data_vector(), lbx=lbx, ubx=ubx)
    theta, R = ml.unpack(sol["x"])
    np.testing.assert_allclose(float(sol["f"]) * ml.n_samples, reference.cost, rtol=1e-8)
    np.testing.assert_allclose(theta, reference.theta, rtol=1e-5, atol=1e-7)
    with pytest.raises(casest.OptionError, match="build the problem from casest.Problem"):
        ml_problem(model, data.n_samples)


@pytest.mark.parametrize("noise", [None, casest.CorrelatedNoise()])
def test_estimator_function_of_a_dynamic_problem_reaches_the_estimate(record, noise):
    from casest.embed import estimator_function

    model, data = record
    problem = casest.Problem(model, data, noise=noise)
    reference = casest.estimate(problem)
    F = estimator_function(problem)
    theta, R = F(problem.data_vector(), reference.theta * 1.01)
    theta = np.asarray(theta).reshape(-1)
    np.testing.assert_allclose(problem.cost(theta, np.asarray(R) if noise else np.asarray(R).reshape(-1)),
                               reference.cost, rtol=1e-8)
    np.testing.assert_allclose(theta, reference.theta, rtol=1e-5, atol=1e-7)


def test_estimator_function_of_a_static_problem_with_fixed_parameters(record):
    """The Problem route on a static model with a fixed parameter and known noise equals estimate()."""
    from casest.embed import estimator_function

    scalar2 = casest.load_model_file("scalar2")
    model, data = scalar2.model(), scalar2.simulate(0)
    problem = casest.Problem(model, data, fixed={"d": 0.0}, noise=casest.KnownNoise({"z": 0.3}))
    reference = casest.estimate(problem)
    theta, R = estimator_function(problem)(problem.data_vector(), problem.vector(reference.theta) + 0.01)
    np.testing.assert_allclose(np.asarray(theta).reshape(-1), problem.vector(reference.theta), rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(np.asarray(R).reshape(-1), [0.09], rtol=1e-12)
