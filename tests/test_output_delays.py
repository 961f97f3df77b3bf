"""Output time delays as estimated parameters (the simulated output sequence interpolated).

Truth: the oscillator of test_delays with its displacement channel measured 0.13 s (6.5
samples) late; the delayed output is computed from a simulation on a grid 50x finer than the
record, read at t - 0.13 s (not by the interpolation under test); white noise with a fixed
seed. The estimate is within 3 std of every true value, both stage-2 solvers reach the same
cost, and the delayed outputs' Jacobian equals finite differences of the simulation.
"""

import casadi as ca
import numpy as np
import pytest

import casest
from casest.data.dataset import DataError
from casest.errors import ModelError, OptionError
from casest.problem.measurement import measurement_of
from casest.filters.ekf import ekf_step_functions

from test_delays import DT, TAU, multisine

N = 1500
TRUTH = {"a": 0.3, "k": 3.0, "c": 1.7, "d": -0.4, "tau": TAU}
FEW = casest.SweepSettings(n_candidates=200)  # three nonlinear parameters; the basin is wide


def oscillator(delays, **options) -> casest.DynamicModel:
    x, v, u, a, k, c, d = (ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "c", "d"))
    P = casest.Parameter
    params = [P("a", 0.05, 2.0, 0.5), P("k", 0.5, 8.0, 2.0), P("c", -5.0, 5.0, 1.0), P("d", -5.0, 5.0, 0.0)]
    if "tau" in delays.values():
        params.append(P("tau", 0.0, 0.3, 0.05, unit="s"))
    return casest.DynamicModel(params, [casest.State("x", 0.0), casest.State("v", 0.0)], ["u"],
                               {"x": v, "v": -k * x - a * v + u}, {"y1": c * x + d, "y2": v},
                               name="output_delay_oscillator", delays=delays, sample_time=DT, **options)


def truth_outputs(t: np.ndarray) -> np.ndarray:
    """y1 at t - TAU and y2 at t, from a simulation 50x finer than the record (RK4, linear reading)."""
    plain = oscillator({})
    fine = np.arange(0.0, t[-1] + DT / 100, DT / 50)
    zeros = np.zeros(fine.size)
    _, y = casest.DynamicModel(
        plain.parameters, plain.states, ["u"], {"x": ca.SX.sym("v"), "v": -ca.SX.sym("k") * ca.SX.sym("x")
                                                - ca.SX.sym("a") * ca.SX.sym("v") + ca.SX.sym("u")},
        {"y1": ca.SX.sym("c") * ca.SX.sym("x") + ca.SX.sym("d"), "y2": ca.SX.sym("v")},
    ).simulate({k: TRUTH[k] for k in "akcd"}, plain.dataset({"t": fine, "u": multisine(fine), "y1": zeros,
                                                             "y2": zeros}))
    return np.column_stack([np.interp(np.maximum(t - TAU, 0.0), fine, y[:, 0]), np.interp(t, fine, y[:, 1])])


def record(model: casest.DynamicModel, seed: int) -> casest.Dataset:
    t = np.arange(N) * DT
    z = truth_outputs(t) + np.random.default_rng([seed, 17]).standard_normal((N, 2)) * [0.05, 0.02]
    return model.dataset({"t": t, "u": multisine(t), "y1": z[:, 0], "y2": z[:, 1]})


def test_an_output_delay_of_013_s_is_recovered_within_three_std():
    model = oscillator({"y1": "tau"})
    est = casest.estimate(model, record(model, 1), sweep_settings=FEW)
    assert est.success, est.notes
    z = (est.theta - model.vector(TRUTH)) / est.std
    assert np.all(np.abs(z) < 3), dict(zip(model.parameter_names, z))
    assert est.std[model.parameter_names.index("tau")] < 0.01  # under half a sample


def test_gauss_newton_and_ipopt_reach_the_same_optimum_with_an_output_delay():
    model = oscillator({"y1": "tau"})
    problem = casest.Problem(model, record(model, 2))
    start = model.vector(TRUTH) * 0.95
    gn = casest.solve_stage2(problem, theta0=start, settings=casest.SolverSettings(output_error_solver="gauss-newton"))
    ip = casest.solve_stage2(problem, theta0=start, settings=casest.SolverSettings(output_error_solver="ipopt"))
    assert gn.success and ip.success
    assert gn.cost == pytest.approx(ip.cost, rel=1e-8)
    assert gn.cost == pytest.approx(problem.cost(gn.theta), rel=1e-12)  # the cost the pipeline compares


def test_delayed_outputs_and_their_jacobian_match_the_simulation():
    """The compiled sensitivities of the delayed outputs against central differences of the
    simulated, delayed outputs (a delay under one sample uses the next sample too)."""
    model = oscillator({"y1": "tau"})
    data = record(model, 3)
    for tau in (0.013, 0.13):
        theta = model.vector({**TRUTH, "tau": tau})
        y, J = measurement_of(model).prediction_and_jacobian(theta, data)
        np.testing.assert_allclose(y, model.predict_data(theta, data).reshape(-1), atol=1e-12)
        for i in range(model.n_parameters):
            step = np.zeros_like(theta)
            step[i] = 1e-6
            fd = (model.predict_data(theta + step, data) - model.predict_data(theta - step, data)).reshape(-1) / 2e-6
            np.testing.assert_allclose(J[:, i], fd, atol=1e-6 * max(1.0, np.max(np.abs(fd))))


def test_a_whole_sample_delay_shifts_the_output_exactly():
    """At tau = 3 dt the kernel's weights are 0, 0, 0, 1, 0 ...: the output three samples earlier,
    the first value held before the record."""
    model = oscillator({"y1": 3 * DT})
    plain = oscillator({})
    data = record(model, 4)
    theta = plain.vector({k: TRUTH[k] for k in "akcd"})
    shifted = model.predict_data(theta, data)[:, 0]
    y = plain.predict_data(theta, plain.dataset({n: data.column(n) for n in ("t", "u", "y1", "y2")}))[:, 0]
    np.testing.assert_allclose(shifted, np.concatenate([[y[0]] * 3, y[:-3]]), atol=1e-12)


def test_fixing_a_delay_parameter_makes_it_a_known_delay():
    model = oscillator({"y1": "tau"})
    data = record(model, 5)
    fixed = model.with_fixed({"tau": 0.06})
    assert "tau" not in fixed.parameter_names and fixed.output_delays.delays == {"y1": 0.06}
    theta = model.vector({**TRUTH, "tau": 0.06})
    np.testing.assert_allclose(fixed.predict_data(fixed.vector({k: TRUTH[k] for k in "akcd"}), data),
                               model.predict_data(theta, data), atol=1e-12)


def test_output_delays_are_refused_where_they_cannot_apply():
    model = oscillator({"y1": "tau"})
    data = record(model, 6)
    with pytest.raises(OptionError, match="single shooting"):
        casest.solve_stage2(casest.Problem(model, data), theta0=model.vector(TRUTH),
                            settings=casest.SolverSettings(shooting="multiple"))
    with pytest.raises(OptionError, match="filters measure each sample's own state"):
        ekf_step_functions(model)  # the step every filter and filter-error ML builds on
    with pytest.raises(ModelError, match="not an input or an output"):
        oscillator({"z": "tau"})
    with pytest.raises(ModelError, match="finite number"):
        oscillator({"y1": -0.1})
    t = np.arange(50) * DT
    t[10:] += 0.3 * DT  # one uneven interval
    with pytest.raises(DataError, match="sample_time"):
        model.check_data(model.dataset({"t": t, "u": np.zeros(50), "y1": np.zeros(50), "y2": np.zeros(50)}))
