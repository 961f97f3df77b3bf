"""The time-varying filter's innovations and derivatives by the compiled loop
(casest.filter_error.sensitivities), and the exact Hessian by its adjoint
(casest.filter_error.hessian).

Truth: CasADi's Jacobian and Hessian of the same record's graph (``InnovationDerivatives``,
``ca.hessian`` of V: automatic differentiation through the EKF's fold), to 1e-10 (derivatives)
and 1e-9 (Hessian) relative to each array's largest entry, on the nonlinear longitudinal model
(4 states, 15 parameters) with missing outputs; and the whole scoring estimate equal to the
graph path's (same iterations, cost to 1e-12 relative, std to 1e-7)."""

import os

import casadi as ca
import numpy as np
import pytest

import casest
from casest._casadi.numerics import compiler_available
from casest.filter_error.nlp import filter_error_step, time_varying_columns, time_varying_graph
from casest.filter_error.hessian import FilterPassHessian, filter_hessian_loops
from casest.filter_error.sensitivities import FilterPassDerivatives, filter_pass_loop
from casest.filter_error.scoring import InnovationDerivatives

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

pytestmark = pytest.mark.skipif(not compiler_available(), reason="the loop needs a C compiler")


def _longitudinal(n_samples=150, missing=True):
    mf = casest.load_model_file(os.path.join(REPO, "models", "longitudinal.py"))
    model, full = mf.model(), mf.simulate(0)
    columns = {"t": full.signals[:n_samples, 0]}
    columns.update({name: full.signals[:n_samples, 1 + k] for k, name in enumerate(s.name for s in model.inputs)})
    outputs = full.outputs[:n_samples].copy()
    if missing:
        outputs[5::9, 0] = np.nan
        outputs[7::13, 2] = np.nan
    columns.update({name: outputs[:, j] for j, name in enumerate(model.output_names)})
    return mf, model, model.dataset(columns, missing="allow" if missing else "error")


def test_the_compiled_filter_pass_equals_the_graphs_jacobian():
    mf, model, data = _longitudinal()
    N, n, ny = data.n_samples, model.n_states, model.n_outputs
    P0 = np.diag(np.linspace(1e-3, 4e-3, n))
    graph = time_varying_graph(model, N, P0)
    theta, q, r, D, last, d0 = graph.symbols
    w, p = ca.vertcat(theta, q, r), ca.vertcat(ca.vec(D), last, d0)
    loop = filter_pass_loop(model, filter_error_step(model), w.numel())
    compiled = FilterPassDerivatives(w, p, graph.E, graph.S, graph.filter_pass, loop, 0)
    reference = InnovationDerivatives(w, p, graph.E, graph.S)
    D_values, last_values = time_varying_columns(model, data)
    p_values = np.concatenate([D_values.reshape(-1, order="F"), last_values, model.initial_values(data)])
    rng = np.random.default_rng(3)
    w_values = np.concatenate([model.vector(mf.TRUTH) * (1 + 0.05 * rng.standard_normal(model.n_parameters)),
                               rng.uniform(1e-4, 1e-2, n), rng.uniform(1e-5, 1e-3, ny)])
    for ours, expected in zip(compiled(w_values, p_values), reference(w_values, p_values)):
        assert ours.shape == expected.shape
        np.testing.assert_allclose(ours, expected, rtol=1e-10, atol=1e-10 * max(np.abs(expected).max(), 1e-300))


@pytest.mark.parametrize("options", [{}, {"R": [1e-4, 2e-4, 1e-4, 5e-3, 1e-3], "estimate_process_noise": False}],
                         ids=["defaults", "R and q held"])
def test_scoring_with_the_compiled_pass_equals_the_graph_path(monkeypatch, options):
    import casest.filter_error.sensitivities as sensitivities
    from casest.filter_error import nlp as filter_error_nlp

    mf, model, data = _longitudinal(n_samples=300, missing=False)
    filter_error_nlp._SYMBOLIC.clear()
    fast = casest.filter_error_estimate(model, data, {"u": 0.1, "w": 0.1}, formulation="time-varying", **options)
    asked = []
    monkeypatch.setattr(sensitivities, "filter_pass_loop", lambda *args: asked.append(args) or (None, None))
    filter_error_nlp._SYMBOLIC.clear()  # the graph path builds its own derivatives
    try:
        graph = casest.filter_error_estimate(model, data, {"u": 0.1, "w": 0.1}, formulation="time-varying",
                                             **options)
    finally:
        filter_error_nlp._SYMBOLIC.clear()  # no graph-path NLP left for later tests
    assert asked  # the second estimate was refused the loop: CasADi's Jacobian and Hessian of the graph
    assert fast.success and graph.success
    assert fast.n_iterations == graph.n_iterations
    assert fast.cost == pytest.approx(graph.cost, rel=1e-12)
    np.testing.assert_allclose(fast.theta, graph.theta, rtol=0, atol=1e-6 * np.max(fast.std))
    # the default covariance, the exact Hessian: by the adjoint of the loop against the graph's
    np.testing.assert_allclose(fast.std, graph.std, rtol=1e-7)


def test_the_adjoint_hessian_of_the_filter_equals_the_graphs():
    """w -> (theta, q, r) as the estimate's NLP maps it (q and r through exp, whose curvature the
    Hessian carries), missing outputs, a random point."""
    mf, model, data = _longitudinal()
    N, n, ny = data.n_samples, model.n_states, model.n_outputs
    graph = time_varying_graph(model, N, np.diag(np.linspace(1e-3, 4e-3, n)))
    theta, q, r, D, last, d0 = graph.symbols
    w_theta, w_q, w_r = ca.MX.sym("w_theta", theta.numel()), ca.MX.sym("w_q", n), ca.MX.sym("w_r", ny)
    natural = [w_theta * ca.DM(model.scales), ca.exp(w_q), ca.exp(w_r)]
    w, p = ca.vertcat(w_theta, w_q, w_r), ca.vertcat(ca.vec(D), last, d0)
    E, S, V = ca.substitute([graph.E, graph.S, graph.V], [theta, q, r], natural)
    filter_pass = tuple(ca.substitute(list(graph.filter_pass[:4]), [theta, q, r], natural)) + graph.filter_pass[4:]
    steps = filter_error_step(model)
    derivatives = FilterPassDerivatives(w, p, E, S, filter_pass, filter_pass_loop(model, steps, w.numel()), 0)
    hessian = FilterPassHessian(derivatives, w, p, filter_pass, filter_hessian_loops(model, steps, w.numel()))
    D_values, last_values = time_varying_columns(model, data)
    p_values = np.concatenate([D_values.reshape(-1, order="F"), last_values, model.initial_values(data)])
    rng = np.random.default_rng(5)
    w_values = np.concatenate([model.vector(mf.TRUTH) / model.scales * (1 + 0.05 * rng.standard_normal(theta.numel())),
                               np.log(rng.uniform(1e-4, 1e-2, n)), np.log(rng.uniform(1e-5, 1e-3, ny))])
    expected = np.asarray(ca.Function("graph_hessian", [w, p], [ca.hessian(V, w)[0]])(w_values, p_values))
    np.testing.assert_allclose(hessian(w_values, p_values), expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
