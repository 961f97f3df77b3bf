"""NIST StRD reader and protocol (certified values from the NIST files themselves)."""

import glob
import os

import casadi as ca
import numpy as np
import pytest

from casest.apps.nist import FormulaError, log_relative_error, parse_formula, read_nist, solve_protocol
from casest.two_stage.symmetry import in_labels_of

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


@pytest.mark.parametrize("start", [1, 2])
@pytest.mark.parametrize("path", FILES, ids=[os.path.basename(f) for f in FILES])
def test_protocol_reaches_certified_values(path, start):
    """One start and its box only: >= 6 correct digits in every parameter, >= 3 in every std.

    From start 2 Gauss2 ended at 25x the certified RSS with ``success`` True before the
    bound multipliers were initialised from mu (IPOPT ``bound_mult_init_method``) and the
    pipeline refined several stage-1 minima.
    """
    pr = read_nist(path, start=start)
    np.testing.assert_array_equal(pr.model.nominal, pr.start1 if start == 1 else pr.start2)
    est = solve_protocol(pr)
    # casest labels symmetric models canonically (ENSO's cycles in ascending period); NIST's labels here
    theta, std = in_labels_of(pr.model, pr.data.signals, est.theta, est.std, pr.certified)
    assert log_relative_error(theta, pr.certified).min() >= 6, (theta, pr.certified)
    assert log_relative_error(std, pr.certified_std).min() >= 3, (std, pr.certified_std)


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


def test_deep_nesting_is_a_formula_error():
    """10 000 nested brackets: a FormulaError naming the depth, not Python's RecursionError."""
    syms = {"b1": ca.SX.sym("b1"), "x": ca.SX.sym("x")}
    with pytest.raises(FormulaError, match="deep"):
        parse_formula("(" * 10000 + "b1*x" + ")" * 10000, syms)
    with pytest.raises(FormulaError, match="deep"):
        parse_formula("-" * 10000 + "b1", syms)
    # nesting of ordinary depth still parses
    f = ca.Function("f", [syms["b1"], syms["x"]], [parse_formula("(" * 50 + "b1*x" + ")" * 50, syms)])
    assert float(f(2.0, 3.0)) == 6.0


def _write_nist(path, formula_lines, start_lines, data_header, rows, rss="0.0", dof=17):
    """A file in the NIST StRD layout: formula lines from line 34, parameters from line 41."""
    lines = [""] * 60
    lines[0] = "NIST/ITL StRD"
    lines[1] = "Dataset Name:  Fake (Fake.dat)"
    lines[4] = f"               Starting Values   (lines 41 to {40 + len(start_lines)})"
    lines[5] = f"               Certified Values  (lines 41 to {45 + len(start_lines)})"
    lines[6] = f"               Data              (lines 61 to {60 + len(rows)})"
    lines[30] = "Model:         Miscellaneous Class"
    lines[31] = f"               {len(start_lines)} Parameters (b1 to b{len(start_lines)})"
    for k, text in enumerate(formula_lines):
        lines[33 + k] = "               " + text
    lines[37] = "          Starting values                  Certified Values"
    for k, text in enumerate(start_lines):
        lines[40 + k] = text
    lines[44] = f"Residual Sum of Squares:                    {rss}"
    lines[46] = f"Degrees of Freedom:                                {dof}"
    lines[59] = data_header
    lines += rows
    path.write_text("\n".join(lines) + "\n")
    return path


def test_constant_line_and_second_start(tmp_path):
    """Roszman1's layout: ``pi = 3.14...`` on a line of its own before the model; start 2 read."""
    x = np.linspace(-4000.0, -1000.0, 25)
    b = np.array([0.2, -6e-6, 1200.0, -180.0])
    y = b[0] - b[1] * x - np.arctan(b[2] / (x - b[3])) / np.pi
    path = _write_nist(
        tmp_path / "Fake.dat",
        ["pi = 3.141592653589793238462643383279E0", "y =  b1 - b2*x - arctan[b3/(x-b4)]/pi  +  e"],
        ["  b1 =   0.1         0.2          0.2  0.01",
         "  b2 =  -0.00001    -0.000005    -6e-6  1e-7",
         "  b3 =   1000        1200         1200  10",
         "  b4 =  -100        -150         -180  1"],
        "Data:  y   x",
        [f"  {a:.17g}  {c:.17g}" for a, c in zip(y, x)],
        dof=21,
    )
    pr = read_nist(path, start=2)
    assert pr.start == 2 and "pi" not in pr.model.parameter_names
    np.testing.assert_array_equal(pr.model.nominal, [0.2, -0.000005, 1200, -150])
    assert pr.rss(b) < 1e-25  # the constant entered the model as pi
    b3 = pr.model.parameter_names.index("b3")
    if "b3" not in pr.linear:  # the box follows start 2
        assert pr.model.lower_bounds[b3] == pytest.approx(1.2)
    with pytest.raises(ValueError, match="start must be 1 or 2"):
        read_nist(path, start=3)


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


# The model formulas of all 27 NIST StRD nonlinear-regression problems, as printed in the
# files, with the same function written in NumPy. The parser must read every one.
_ALL_27 = {
    "Misra1a": ("b1*(1-exp[-b2*x])", lambda b, x: b[0] * (1 - np.exp(-b[1] * x))),
    "Chwirut1": ("exp(-b1*x)/(b2+b3*x)", lambda b, x: np.exp(-b[0] * x) / (b[1] + b[2] * x)),
    "Chwirut2": ("exp(-b1*x)/(b2+b3*x)", lambda b, x: np.exp(-b[0] * x) / (b[1] + b[2] * x)),
    "Lanczos1": ("b1*exp(-b2*x) + b3*exp(-b4*x) + b5*exp(-b6*x)",
                 lambda b, x: b[0] * np.exp(-b[1] * x) + b[2] * np.exp(-b[3] * x) + b[4] * np.exp(-b[5] * x)),
    "Gauss1": ("b1*exp( -b2*x ) + b3*exp( -(x-b4)**2 / b5**2 ) + b6*exp( -(x-b7)**2 / b8**2 )",
               lambda b, x: b[0] * np.exp(-b[1] * x) + b[2] * np.exp(-(x - b[3]) ** 2 / b[4] ** 2)
               + b[5] * np.exp(-(x - b[6]) ** 2 / b[7] ** 2)),
    "DanWood": ("b1*x**b2", lambda b, x: b[0] * x ** b[1]),
    "Misra1b": ("b1 * (1-(1+b2*x/2)**(-2))", lambda b, x: b[0] * (1 - (1 + b[1] * x / 2) ** (-2))),
    "Kirby2": ("(b1 + b2*x + b3*x**2) / (1 + b4*x + b5*x**2)",
               lambda b, x: (b[0] + b[1] * x + b[2] * x**2) / (1 + b[3] * x + b[4] * x**2)),
    "Hahn1": ("(b1+b2*x+b3*x**2+b4*x**3) / (1+b5*x+b6*x**2+b7*x**3)",
              lambda b, x: (b[0] + b[1] * x + b[2] * x**2 + b[3] * x**3) / (1 + b[4] * x + b[5] * x**2 + b[6] * x**3)),
    "Nelson": ("b1 - b2*x1 * exp[-b3*x2]", None),
    "MGH17": ("b1 + b2*exp[-x*b4] + b3*exp[-x*b5]",
              lambda b, x: b[0] + b[1] * np.exp(-x * b[3]) + b[2] * np.exp(-x * b[4])),
    "Lanczos2": ("b1*exp(-b2*x) + b3*exp(-b4*x) + b5*exp(-b6*x)",
                 lambda b, x: b[0] * np.exp(-b[1] * x) + b[2] * np.exp(-b[3] * x) + b[4] * np.exp(-b[5] * x)),
    "Gauss2": ("b1*exp( -b2*x ) + b3*exp( -(x-b4)**2 / b5**2 ) + b6*exp( -(x-b7)**2 / b8**2 )",
               lambda b, x: b[0] * np.exp(-b[1] * x) + b[2] * np.exp(-(x - b[3]) ** 2 / b[4] ** 2)
               + b[5] * np.exp(-(x - b[6]) ** 2 / b[7] ** 2)),
    "Gauss3": ("b1*exp( -b2*x ) + b3*exp( -(x-b4)**2 / b5**2 ) + b6*exp( -(x-b7)**2 / b8**2 )",
               lambda b, x: b[0] * np.exp(-b[1] * x) + b[2] * np.exp(-(x - b[3]) ** 2 / b[4] ** 2)
               + b[5] * np.exp(-(x - b[6]) ** 2 / b[7] ** 2)),
    "Misra1c": ("b1 * (1-(1+2*b2*x)**(-.5))", lambda b, x: b[0] * (1 - (1 + 2 * b[1] * x) ** (-0.5))),
    "Misra1d": ("b1*b2*x*((1+b2*x)**(-1))", lambda b, x: b[0] * b[1] * x * ((1 + b[1] * x) ** (-1))),
    "Roszman1": ("b1 - b2*x - arctan[b3/(x-b4)]/pi", lambda b, x: b[0] - b[1] * x - np.arctan(b[2] / (x - b[3])) / np.pi),
    "ENSO": ("b1 + b2*cos( 2*pi*x/12 ) + b3*sin( 2*pi*x/12 ) + b5*cos( 2*pi*x/b4 ) + b6*sin( 2*pi*x/b4 )"
             " + b8*cos( 2*pi*x/b7 ) + b9*sin( 2*pi*x/b7 )",
             lambda b, x: b[0] + b[1] * np.cos(2 * np.pi * x / 12) + b[2] * np.sin(2 * np.pi * x / 12)
             + b[4] * np.cos(2 * np.pi * x / b[3]) + b[5] * np.sin(2 * np.pi * x / b[3])
             + b[7] * np.cos(2 * np.pi * x / b[6]) + b[8] * np.sin(2 * np.pi * x / b[6])),
    "MGH09": ("b1*(x**2+x*b2) / (x**2+x*b3+b4)", lambda b, x: b[0] * (x**2 + x * b[1]) / (x**2 + x * b[2] + b[3])),
    "Thurber": ("(b1 + b2*x + b3*x**2 + b4*x**3) / (1 + b5*x + b6*x**2 + b7*x**3)",
                lambda b, x: (b[0] + b[1] * x + b[2] * x**2 + b[3] * x**3) / (1 + b[4] * x + b[5] * x**2 + b[6] * x**3)),
    "BoxBOD": ("b1*(1-exp[-b2*x])", lambda b, x: b[0] * (1 - np.exp(-b[1] * x))),
    "Rat42": ("b1 / (1+exp[b2-b3*x])", lambda b, x: b[0] / (1 + np.exp(b[1] - b[2] * x))),
    "MGH10": ("b1 * exp[b2/(x+b3)]", lambda b, x: b[0] * np.exp(b[1] / (x + b[2]))),
    "Eckerle4": ("(b1/b2) * exp[-0.5*((x-b3)/b2)**2]", lambda b, x: (b[0] / b[1]) * np.exp(-0.5 * ((x - b[2]) / b[1]) ** 2)),
    "Rat43": ("b1 / ((1+exp[b2-b3*x])**(1/b4))", lambda b, x: b[0] / ((1 + np.exp(b[1] - b[2] * x)) ** (1 / b[3]))),
    "Bennett5": ("b1 * (b2+x)**(-1/b3)", lambda b, x: b[0] * (b[1] + x) ** (-1 / b[2])),
    "Lanczos3": ("b1*exp(-b2*x) + b3*exp(-b4*x) + b5*exp(-b6*x)",
                 lambda b, x: b[0] * np.exp(-b[1] * x) + b[2] * np.exp(-b[3] * x) + b[4] * np.exp(-b[5] * x)),
}


@pytest.mark.parametrize("name", sorted(_ALL_27))
def test_parser_reads_all_27_nist_formulas(name):
    text, reference = _ALL_27[name]
    b = [ca.SX.sym(f"b{i}") for i in range(1, 10)]
    syms = {f"b{i + 1}": s for i, s in enumerate(b)} | {n: ca.SX.sym(n) for n in ("x", "x1", "x2")}
    expr = parse_formula(text, syms)
    if reference is None:  # Nelson: two predictors
        f = ca.Function("f", [ca.vertcat(*b), syms["x1"], syms["x2"]], [expr])
        np.testing.assert_allclose(float(f(np.arange(1, 10) / 10, 2.0, 3.0)), 0.1 - 0.2 * 2.0 * np.exp(-0.3 * 3.0), rtol=1e-14)
        return
    f = ca.Function("f", [ca.vertcat(*b), syms["x"]], [expr])
    bv = np.array([1.3, 0.7, 2.1, 5.3, 1.7, 0.4, 8.9, 2.2, 0.6])
    for x in (1.5, 4.2, 7.7):
        np.testing.assert_allclose(float(f(bv, x)), reference(bv, x), rtol=1e-13)
