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
