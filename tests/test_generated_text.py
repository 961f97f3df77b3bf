"""The text pass over CasADi's generated C that drops its pointer tests
(casest._casadi.generated_text.given_pointers): a source of one Function loses every test and,
compiled, computes what CasADi computes (truth: CasADi's own evaluation, to rounding); a source
whose Function calls another is left unchanged (a called Function may be given a null pointer for
an argument it does not need: dropping its tests would read through it)."""

import ctypes
import shutil
import subprocess

import casadi as ca
import numpy as np
import pytest

from casest._casadi.generated_text import given_pointers

CC = shutil.which("cc") or shutil.which("gcc")


def _source(f: ca.Function) -> str:
    generator = ca.CodeGenerator(f.name() + ".c", {"casadi_int": "long long"})
    generator.add(f)
    return generator.dump()


def test_one_functions_pointer_tests_are_dropped_and_it_computes_the_same(tmp_path):
    x, y = ca.SX.sym("x", 2), ca.SX.sym("y")
    f = ca.Function("kernel", [x, y], [ca.vertcat(ca.sin(x[0]) * y, ca.cos(x[0]) + x[1]), ca.sqrt(y) * x[1]])
    text = given_pointers(_source(f))
    assert "arg[0]?" not in text and "!=0) res[" not in text
    assert "arg[0][0]" in text and "arg[1][0]" in text
    if CC is None:
        pytest.skip("no C compiler on this machine")
    (tmp_path / "kernel.c").write_text(text)
    library = tmp_path / "kernel.so"
    subprocess.run([CC, "-O2", "-shared", "-fPIC", str(tmp_path / "kernel.c"), "-o", str(library), "-lm"], check=True)
    kernel = ctypes.CDLL(str(library)).kernel
    xv, yv = np.array([0.7, -1.3]), np.array([2.5])
    out0, out1 = np.zeros(2), np.zeros(1)
    arg = (ctypes.c_void_p * 2)(xv.ctypes.data, yv.ctypes.data)
    res = (ctypes.c_void_p * 2)(out0.ctypes.data, out1.ctypes.data)
    assert kernel(arg, res, None, None, 0) == 0
    expected = f(xv, yv)
    np.testing.assert_allclose(out0, np.asarray(expected[0]).ravel(), rtol=1e-15)
    np.testing.assert_allclose(out1, np.asarray(expected[1]).ravel(), rtol=1e-15)


def test_a_source_whose_function_calls_another_is_unchanged():
    x, y = ca.SX.sym("x", 2), ca.SX.sym("y")
    called = ca.Function("called", [x, y], [ca.sin(x[0]) * y, x[1]], {"never_inline": True})
    f = ca.Function("caller", [x, y], [called(x, y)[0] + 1])
    text = _source(f)
    assert "arg[0]?" in text or "arg[1]?" in text  # the tests the pass would drop are there
    assert given_pointers(text) == text
