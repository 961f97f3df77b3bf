"""Output error by Gauss-Newton against the exact-Hessian IPOPT path (summary Sec. 5.2, Eq. 5.8-5.9).

Both minimise the same ML cost (paper Eq. 6 through the simulation); the expected value of
every comparison is the IPOPT path's optimum from the same start, to 1e-8 relative in the
cost (the issue's criterion) and 1e-4 std in the parameters.
"""

from __future__ import annotations

import os

import casadi as ca
import numpy as np
import pytest

import casest
from casest.backend.ipopt import SolverSettings
from casest._casadi.numerics import compiler_available
from casest.backend.sensitivities import output_sensitivities
from casest.errors import OptionError

from test_dynamic import TRUTH, oscillator, oscillator_data

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GN, IPOPT = SolverSettings(output_error_solver="gauss-newton"), SolverSettings(output_error_solver="ipopt")


def _both(problem, start):
    gn = casest.solve_stage2(problem, theta0=start, settings=GN)
    ip = casest.solve_stage2(problem, theta0=start, settings=IPOPT)
    return gn, ip


@pytest.mark.parametrize("name", ["short_period", "data_compatibility"])
def test_gauss_newton_reaches_the_ipopt_optimum(name):
    mf = casest.load_model_file(os.path.join(REPO, "models", f"{name}.py"))
    model = mf.model()
    problem = casest.Problem(model, mf.simulate(0))
    start = model.vector(mf.TRUTH) * 0.9
    gn, ip = _both(problem, start)
    assert gn.cost == pytest.approx(ip.cost, rel=1e-8)
    assert gn.success and ip.success
    # parameters: within 1e-4 of their std (the std of the IPOPT optimum's exact Hessian)
    est = casest.estimate(model, problem.data, start=dict(zip(model.parameter_names, ip.theta)), mode="full",
                          solver_settings=IPOPT)
    assert np.all(np.abs(gn.theta - ip.theta) <= 1e-4 * est.std)
    np.testing.assert_allclose(gn.R, ip.R, rtol=1e-6)


def test_gauss_newton_with_known_noise_missing_outputs_and_a_bound():
    """Known R, 30 % of one channel missing and an upper bound below the truth of ``k``: the
    bounded Gauss-Newton holds k on its bound as IPOPT does, and both reach the same cost."""
    P = casest.Parameter
    base = oscillator()
    data = oscillator_data(base, seed=3, n=600)
    y2 = data.outputs[:, 1].copy()
    y2[np.random.default_rng(8).random(y2.size) < 0.3] = np.nan
    gappy = base.dataset({"t": data.signals[:, 0], "u": data.signals[:, 1], "y1": data.outputs[:, 0], "y2": y2},
                         missing="allow")
    x, v, u, a, k, c, d = (ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "c", "d"))
    bounded = casest.DynamicModel(
        [P("a", 0.05, 2.0, 0.5), P("k", 0.5, 2.9, 2.0), P("c", -5.0, 5.0, 1.0), P("d", -5.0, 5.0, 0.0)],
        [casest.State("x", 0.0), casest.State("v", 0.0)], ["u"], {"x": v, "v": -k * x - a * v + u},
        {"y1": c * x + d, "y2": v}, name="oscillator_bounded")
    problem = casest.Problem(bounded, gappy, noise=casest.KnownNoise({"y1": 0.05, "y2": 0.02}))
    start = bounded.vector({"a": 0.4, "k": 2.0, "c": 1.5, "d": 0.0})
    gn, ip = _both(problem, start)
    assert gn.success and ip.success
    assert gn.cost == pytest.approx(ip.cost, rel=1e-8)
    assert gn.theta[1] == pytest.approx(2.9, abs=1e-9)  # held on the bound
    np.testing.assert_allclose(gn.theta, ip.theta, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(gn.R, [0.05**2, 0.02**2])


@pytest.mark.parametrize("jit", [False, True])
def test_sensitivities_equal_casadi_ad_of_the_simulated_outputs(jit):
    """dy/dtheta of the first-order pass against CasADi's AD of the simulation (1e-10): the
    CasADi graph, and (jit) the compiled C loop over the record."""
    model = oscillator()
    data = oscillator_data(model, n=300)
    problem = casest.Problem(model, data)
    theta = model.vector(TRUTH) * 1.1
    sensitivities = output_sensitivities(model, data.n_samples, jit=jit)
    if jit and compiler_available():
        assert sensitivities.compiled_loop  # the record pass as one C loop
    y, J = sensitivities(theta, problem.data_vector())
    th = ca.MX.sym("theta", 4)
    T, U = ca.DM(data.signals[:, 0]).T, ca.DM(data.signals[:, 1]).T
    X = model.trajectory_symbols(th, ca.DM.zeros(0, 1), T, U)
    Y = model.output_model.function.map(data.n_samples)(ca.vertcat(X, U), th)
    f = ca.Function("f", [th], [Y.T, ca.jacobian(ca.vec(Y.T), th)])
    Y_ad, J_ad = (np.asarray(v) for v in f(theta))
    np.testing.assert_allclose(y, Y_ad, rtol=1e-12, atol=1e-12)
    J_ad = J_ad.reshape(2, data.n_samples, 4).transpose(1, 0, 2)  # rows of vec(Y'): channel-major
    np.testing.assert_allclose(J, J_ad, rtol=1e-10, atol=1e-10 * np.abs(J_ad).max())


def test_the_compiled_loop_equals_the_graph_with_missing_outputs():
    """The C loop reads the inputs, times and initial data out of the data vector, whose outputs
    carry a mask when some are missing: the same outputs and sensitivities as the graph (1e-12),
    and the outputs-only loop the same outputs (1e-14)."""
    model = oscillator()
    data = oscillator_data(model, n=200)
    y1 = data.column("y1").copy()
    y1[::7] = np.nan
    data = model.dataset({"t": data.column("t"), "u": data.column("u"), "y1": y1, "y2": data.column("y2")},
                         missing="allow")
    problem = casest.Problem(model, data)
    assert problem.masked
    theta = model.vector(TRUTH) * 0.9
    graph = output_sensitivities(model, data.n_samples, masked=True, jit=False)
    loop = output_sensitivities(model, data.n_samples, masked=True, jit=True)
    for a, b in zip(graph(theta, problem.data_vector()), loop(theta, problem.data_vector())):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * np.abs(a).max())
    # the outputs-only pass (a trial point's cost) against the sensitivity pass's outputs
    y = loop(theta, problem.data_vector())[0]
    np.testing.assert_allclose(loop.outputs(theta, problem.data_vector()), y, rtol=1e-14, atol=1e-14 * np.abs(y).max())
    np.testing.assert_array_equal(graph.outputs(theta, problem.data_vector()), graph(theta, problem.data_vector())[0])


def test_gauss_newton_is_refused_where_it_does_not_apply():
    model = oscillator()
    problem = casest.Problem(model, oscillator_data(model, n=200), noise=casest.CorrelatedNoise())
    with pytest.raises(OptionError, match="output_error_solver='gauss-newton'"):
        casest.solve_stage2(problem, theta0=model.vector(TRUTH), settings=GN)
    with pytest.raises(OptionError, match="output_error_solver must be one of"):
        SolverSettings(output_error_solver="newton")
