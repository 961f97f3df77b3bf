"""The two-stage estimator from CasADi primitives (``two_stage_graph_function``) against the
callback one (``two_stage_function``, which runs ``casest.estimate``), and as a CasADi object:
saved and loaded, and code-generated to C that compiles and runs without Python.

Truths: the callback Function's outputs on the paper's scalar example 2 (Eq. 31, its simulated
data, seed 0): theta and R to 1e-10 relative, the covariance to 1e-8 relative (both polish the
same optimum with exact Newton steps); a saved and loaded Function, and the compiled C of the
SQP variant, give the very same numbers as the Function they came from.
"""

import os
import shutil
import subprocess

import casadi as ca
import numpy as np
import pytest

import casest
from casest.interop import two_stage_function, two_stage_graph_function
from casest.models import OptionError


@pytest.fixture(scope="module")
def scalar2():
    m = casest.load_model_file("scalar2")
    return m.model(), m.simulate(seed=0)


def _outputs(F, data):
    return [np.asarray(v, dtype=float) for v in F(data.signals.T, data.outputs.T)]


@pytest.mark.parametrize("solver", ["ipopt", "sqpmethod"])
def test_the_graph_equals_the_callback_estimator(scalar2, solver):
    model, data = scalar2
    graph = _outputs(two_stage_graph_function(model, data.n_samples, solver=solver), data)
    callback = _outputs(two_stage_function(model, data.n_samples), data)
    np.testing.assert_allclose(graph[0], callback[0], rtol=1e-10)
    np.testing.assert_allclose(graph[1], callback[1], rtol=1e-10)
    np.testing.assert_allclose(graph[2], callback[2], rtol=1e-8, atol=1e-14)
    assert graph[3].item() == callback[3].item() == 1.0


@pytest.mark.parametrize("solver", ["ipopt", "sqpmethod"])
def test_saved_and_loaded_it_gives_the_same_numbers(scalar2, solver, tmp_path):
    model, data = scalar2
    F = two_stage_graph_function(model, data.n_samples, sweep_settings=casest.SweepSettings(n_candidates=300),
                                 solver=solver)
    path = str(tmp_path / "two_stage.casadi")
    F.save(path)
    loaded = ca.Function.load(path)
    for a, b in zip(_outputs(F, data), _outputs(loaded, data)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.skipif(shutil.which("gcc") is None and shutil.which("cc") is None, reason="needs a C compiler")
def test_the_sqp_variant_code_generates_to_c_that_runs(scalar2, tmp_path):
    model, data = scalar2
    F = two_stage_graph_function(model, data.n_samples, sweep_settings=casest.SweepSettings(n_candidates=300),
                                 solver="sqpmethod")
    generator = ca.CodeGenerator("two_stage_graph.c")
    generator.add(F)
    generator.generate(str(tmp_path) + os.sep)
    library = tmp_path / "two_stage_graph.so"
    cc = shutil.which("gcc") or shutil.which("cc")
    subprocess.run([cc, "-O1", "-shared", "-fPIC", str(tmp_path / "two_stage_graph.c"), "-o", str(library), "-lm"],
                   check=True, capture_output=True)
    compiled = ca.external(F.name(), str(library))
    for a, b in zip(_outputs(F, data), _outputs(compiled, data)):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-15)


def test_what_it_refuses(scalar2):
    model, data = scalar2
    with pytest.raises(OptionError, match="solver must be one of"):
        two_stage_graph_function(model, data.n_samples, solver="newton")
    with pytest.raises(OptionError, match="positive integer"):
        two_stage_graph_function(model, 0)
    import casadi

    x, a, b = casadi.SX.sym("x"), casadi.SX.sym("a"), casadi.SX.sym("b")
    linear = casest.Model([casest.Parameter("a"), casest.Parameter("b")], ["x"], {"z": a * x + b})
    with pytest.raises(OptionError, match="no nonlinear parameter"):
        two_stage_graph_function(linear, 10)


def test_the_stage1_function_is_the_sweeps_landscape_and_best_candidate(scalar2):
    """Truth: casest.sweep on the same data and the same candidates (its compiled Gram sums, another
    code path): every candidate's Tr[R] to 1e-12 relative, the same best candidate and xi1; theta0
    is the best candidate's parameter vector; SX or MX calls and a saved copy give the same numbers."""
    from casest.interop import stage1_function

    model, data = scalar2
    S = stage1_function(model, data.n_samples)
    out = dict(zip(S.name_out(), S(data.signals.T, data.outputs.T)))
    landscape = casest.sweep(model, data, casest.separate(model))
    np.testing.assert_allclose(np.asarray(out["trace_R"]).ravel(), landscape.trace_R, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(out["xi2"]).T, landscape.candidates, rtol=0, atol=0)
    np.testing.assert_array_equal(np.asarray(out["best_xi2"]).ravel(), landscape.best_xi2)
    np.testing.assert_allclose(np.asarray(out["best_xi1"]).ravel(), landscape.best_xi1, rtol=1e-10)
    assert float(out["best_trace"]) == pytest.approx(np.min(landscape.trace_R), rel=1e-12)
    loaded = ca.Function.deserialize(S.serialize())
    np.testing.assert_array_equal(np.asarray(loaded(data.signals.T, data.outputs.T)[0]),
                                  np.asarray(out["trace_R"]))


def test_the_stage1_function_differentiates_like_finite_differences(scalar2):
    """Its derivatives in the data, from CasADi's AD through the map and the least squares, against
    central finite differences (step h = 1e-6 of the data's scale; agreement to 1e-6 relative or
    to the differences' rounding, 100 eps max|f| / h): the landscape of the first 50 of 200
    candidates and the best candidate's xi1 with respect to the outputs, the landscape with respect
    to the signals, called on MX symbols as inside another NLP."""
    from casest.interop import stage1_function

    model, data = scalar2
    S = stage1_function(model, data.n_samples, casest.SweepSettings(n_candidates=200))
    X, Z = ca.MX.sym("X", *data.signals.T.shape), ca.MX.sym("Z", *data.outputs.T.shape)
    trace, _, _, _, _, best_xi1, _, _ = S(X, Z)
    head = trace[:, :50]
    derivatives = ca.Function("d", [X, Z], [ca.jacobian(head, Z), ca.jacobian(best_xi1, Z), ca.jacobian(head, X)])
    values = ca.Function("v", [X, Z], [head, best_xi1])
    x0, z0 = data.signals.T.copy(), data.outputs.T.copy()
    dZ_trace, dZ_xi1, dX_trace = (np.asarray(ca.densify(d)) for d in derivatives(x0, z0))
    rng = np.random.default_rng(20261205)
    for column in rng.choice(z0.size, 6, replace=False):
        h = 1e-6 * np.max(np.abs(z0))
        up, down = z0.copy(), z0.copy()
        up.flat[column] += h
        down.flat[column] -= h
        (t_up, x_up), (t_down, x_down) = values(x0, up), values(x0, down)
        fd_trace = (np.asarray(t_up) - np.asarray(t_down)).ravel() / (2 * h)
        fd_xi1 = (np.asarray(x_up) - np.asarray(x_down)).ravel() / (2 * h)
        rounding = 100 * np.finfo(float).eps / h
        np.testing.assert_allclose(dZ_trace[:, column], fd_trace, rtol=1e-6, atol=rounding * np.max(np.abs(t_up)))
        np.testing.assert_allclose(dZ_xi1[:, column], fd_xi1, rtol=1e-6, atol=rounding * np.max(np.abs(x_up)))
    for column in rng.choice(x0.size, 3, replace=False):
        h = 1e-6 * np.max(np.abs(x0))
        up, down = x0.copy(), x0.copy()
        up.flat[column] += h
        down.flat[column] -= h
        t_up = np.asarray(values(up, z0)[0])
        fd = (t_up - np.asarray(values(down, z0)[0])).ravel() / (2 * h)
        rounding = 100 * np.finfo(float).eps / h
        np.testing.assert_allclose(dX_trace[:, column], fd, rtol=1e-6, atol=rounding * np.max(np.abs(t_up)))
