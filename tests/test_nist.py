"""NIST StRD reader and protocol (certified values from the NIST files themselves)."""

import glob
import os

import casadi as ca
import numpy as np
import pytest

from casest.nist import FormulaError, log_relative_error, parse_formula, read_nist, solve_protocol

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FILES = sorted(glob.glob(os.path.join(REPO, "data", "nist_strd", "*.dat")))


def test_twelve_files_are_bundled():
    assert len(FILES) == 12


@pytest.mark.parametrize("path", FILES, ids=[os.path.basename(f) for f in FILES])
def test_parsed_model_reproduces_certified_rss(path):
    """NIST certified RSS at the certified parameters, to 1e-8 relative."""
    pr = read_nist(path)
    assert pr.data.n_samples == pr.degrees_of_freedom + len(pr.certified)
    np.testing.assert_allclose(pr.rss(pr.certified), pr.certified_rss, rtol=1e-8)


@pytest.mark.parametrize("path", FILES, ids=[os.path.basename(f) for f in FILES])
def test_protocol_reaches_certified_values(path):
    """Start 1 and the box only: >= 6 correct digits in every parameter, >= 3 in every std."""
    pr = read_nist(path)
    est = solve_protocol(pr)
    assert log_relative_error(est.theta, pr.certified).min() >= 6, (est.theta, pr.certified)
    assert log_relative_error(est.std, pr.certified_std).min() >= 3, (est.std, pr.certified_std)


def test_parser_grammar():
    b1, b2, x = ca.SX.sym("b1"), ca.SX.sym("b2"), ca.SX.sym("x")
    syms = {"b1": b1, "b2": b2, "x": x}
    expr = parse_formula("b1*(1-exp[-b2*x]) + arctan[x]/pi - 2**-1 + .5e0 + 1.0D0", syms)
    f = ca.Function("f", [b1, b2, x], [expr])
    expected = 2 * (1 - np.exp(-0.5 * 3)) + np.arctan(3) / np.pi - 0.5 + 0.5 + 1.0
    np.testing.assert_allclose(float(f(2, 0.5, 3)), expected, rtol=1e-15)
    g = ca.Function("g", [x], [parse_formula("-x**2", syms)])
    assert float(g(3)) == -9.0  # unary minus binds weaker than **, as in Fortran


@pytest.mark.parametrize(
    "formula, message",
    [
        ("b1*__import__('os')", "not allowed"),
        ("b1*eval[x]", "name 'eval'"),
        ("b1 ; b2", "not allowed"),
        ("b1*y", "name 'y'"),
        ("b1*(x", r"expected '\)'"),
        ("b1 = x", "not allowed"),
    ],
)
def test_parser_rejects_anything_outside_the_whitelist(formula, message):
    syms = {"b1": ca.SX.sym("b1"), "b2": ca.SX.sym("b2"), "x": ca.SX.sym("x")}
    with pytest.raises(FormulaError, match=message):
        parse_formula(formula, syms)


def test_transformed_response_and_two_predictors(tmp_path):
    """Nelson-style file: log[y] = b1 - b2*x1 * exp[-b3*x2], two predictors (made-up numbers)."""
    rng = np.random.default_rng(0)
    x1, x2 = rng.uniform(1, 5, 20), rng.uniform(1, 5, 20)
    y = np.exp(2.0 - 0.1 * x1 * np.exp(-0.3 * x2))
    lines = [""] * 60
    lines[0] = "NIST/ITL StRD"
    lines[1] = "Dataset Name:  Fake (Fake.dat)"
    lines[4] = "               Starting Values   (lines 41 to 43)"
    lines[5] = "               Certified Values  (lines 41 to 48)"
    lines[6] = f"               Data              (lines 61 to {60 + len(y)})"
    lines[30] = "Model:         Exponential Class"
    lines[31] = "               3 Parameters (b1 to b3)"
    lines[33] = "               log[y] = b1 - b2*x1 * exp[-b3*x2]  +  e"
    lines[37] = "          Starting values                  Certified Values"
    lines[40] = "  b1 =   2.5         2.1          2.0  0.1"
    lines[41] = "  b2 =   0.2         0.1          0.1  0.01"
    lines[42] = "  b3 =   0.5         0.4          0.3  0.01"
    lines[44] = "Residual Sum of Squares:                    0.0"
    lines[46] = "Degrees of Freedom:                                17"
    lines[47] = "Number of Observations:                           20"
    lines[59] = "Data:  y   x1   x2"
    lines += [f"  {a:.17g}  {b:.17g}  {c:.17g}" for a, b, c in zip(y, x1, x2)]
    path = tmp_path / "Fake.dat"
    path.write_text("\n".join(lines) + "\n")
    pr = read_nist(path)
    assert pr.model.signal_names == ("x1", "x2")
    np.testing.assert_allclose(pr.data.outputs[:, 0], np.log(y), rtol=1e-14)
    assert pr.rss([2.0, 0.1, 0.3]) < 1e-25
