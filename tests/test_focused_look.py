"""The focused second look (casest.two_stage.focused): roles read from the expression graph,
informative ranges from the record, and the look itself on NIST Gauss2 from its box midpoint."""

import os
import sys
import warnings

import casadi as ca
import numpy as np
import pytest

import casest
from casest.status import NoteCode
from casest.problem.separate import separate
from casest.two_stage.sweep.informative import RANGE_MARGIN, draw_informative, informative_box, signal_roles

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "scripts", "campaigns"))
from nets.published_net import published_problem  # noqa: E402


def _peaks_model(box=(1e-3, 1e5)):
    """y = a0 exp(-k x) + a1 exp(-((x - c) / w)^2), every nonlinear parameter in a wide box with a
    uniform prior declared (the default over such a box is log-uniform, which already samples the
    lower decades these tests narrow to)."""
    x = ca.SX.sym("x")
    a0, k, a1, c, w = (ca.SX.sym(n) for n in ("a0", "k", "a1", "c", "w"))
    uniform = casest.Uniform()
    params = [casest.Parameter("a0"), casest.Parameter("k", lb=box[0], ub=box[1], nominal=1.0, prior=uniform),
              casest.Parameter("a1"), casest.Parameter("c", lb=box[0], ub=box[1], nominal=1.0, prior=uniform),
              casest.Parameter("w", lb=box[0], ub=box[1], nominal=1.0, prior=uniform)]
    h = a0 * ca.exp(-k * x) + a1 * ca.exp(-((x - c) / w) ** 2)
    return casest.Model(params, [casest.Signal("x")], {"y": h})


def test_roles_are_read_from_the_expression_graph():
    """k multiplies x (a rate), c is subtracted from x (a shift), w divides x - c (a scale of a
    shifted x); a parameter used in two roles has none."""
    m = _peaks_model()
    part = separate(m)
    roles = dict(zip(part.nonlinear, signal_roles(m, part.nonlinear_index)))
    assert (roles["k"].kind, roles["k"].signal, roles["k"].centred) == ("rate", "x", False)
    assert (roles["c"].kind, roles["c"].sign) == ("shift", 1)
    assert (roles["w"].kind, roles["w"].centred) == ("scale", True)
    x, p, a = ca.SX.sym("x"), ca.SX.sym("p"), ca.SX.sym("a")
    mixed = casest.Model([casest.Parameter("a"), casest.Parameter("p", lb=0.1, ub=10.0, nominal=1.0)],
                         [casest.Signal("x")], {"y": a * ca.exp(-p * x) + ca.sin(p)})
    part = separate(mixed)
    assert signal_roles(mixed, part.nonlinear_index) == [None]


@pytest.mark.parametrize("write, kind, sign", [
    (lambda x, b: ca.exp(-(b * x)), "rate", 1),              # a product, parameter second
    (lambda x, b: ca.exp(-(x * b)), "rate", 1),              # a product, parameter first
    (lambda x, b: ca.exp(-(b * x**2)), "rate2", 1),          # the square of the signal
    (lambda x, b: ca.exp(-(b**2 * x**2)), "rate", 1),        # both squared: (b x)^2
    (lambda x, b: ca.exp(-(x / b)), "scale", 1),             # a divisor
    (lambda x, b: ca.exp(-(x**2 / b**2)), "scale", 1),       # (x / b)^2
    (lambda x, b: ca.exp(-(x**2 / b)), "scale2", 1),         # x^2 / b
    (lambda x, b: ca.exp(-(x - b) ** 2), "shift", 1),        # x - b: zero at b = x
    (lambda x, b: ca.exp(-(x + b) ** 2), "shift", -1),       # x + b: zero at b = -x
    (lambda x, b: ca.exp(-(-b * x)), "rate", 1),             # a negation hands the parameter on
])
def test_every_rule_of_the_role_table_is_read(write, kind, sign):
    """Each rule of ROLE_RULES (and the shift, the negation, the squares) read from a model written
    that way: the truth is the role the expression gives the parameter by construction."""
    x, a, b = ca.SX.sym("x"), ca.SX.sym("a"), ca.SX.sym("b")
    m = casest.Model([casest.Parameter("a"), casest.Parameter("b", lb=0.1, ub=10.0, nominal=1.0)],
                     [casest.Signal("x")], {"y": a * write(x, b)})
    (role,) = signal_roles(m, separate(m).nonlinear_index)
    assert (role.kind, role.signal, role.sign) == (kind, "x", sign)


def test_informative_ranges_come_from_the_record():
    """On x = 10, 10.5, ..., 60: the shift within [10, 60]; the rate within [1 / (10 * 60), 10 / 0.5];
    the scale of x - c within [0.5 / 10, 10 * 50] (the margins of RANGE_MARGIN = 10)."""
    m = _peaks_model()
    x = np.arange(10.0, 60.0 + 1e-9, 0.5)
    data = casest.Dataset(m, {"x": x, "y": np.exp(-0.05 * x) + np.exp(-((x - 30.0) / 5.0) ** 2)})
    part = separate(m)
    box = informative_box(m, part, data)
    ranges = dict(zip(box.names, zip(box.lower, box.upper)))
    assert RANGE_MARGIN == 10.0
    assert ranges["c"] == pytest.approx((10.0, 60.0))
    assert ranges["k"] == pytest.approx((1.0 / 600.0, 20.0))
    assert ranges["w"] == pytest.approx((0.05, 500.0))
    assert set(box.narrowed) == {"c", "k", "w"}
    cands = draw_informative(m, part, box, 256, seed=0)
    assert cands.shape == (256, 3)
    assert np.all(cands >= box.lower) and np.all(cands <= box.upper)


def test_a_box_the_record_informs_throughout_gets_no_second_look():
    """Boxes already inside the informative ranges: nothing is narrowed, no box."""
    m = _peaks_model(box=(0.1, 1.0))
    x = np.linspace(0.0, 10.0, 101)
    data = casest.Dataset(m, {"x": x, "y": np.exp(-0.5 * x)})
    m2 = m.with_bounds({"c": (1.0, 9.0), "k": (0.1, 1.0), "w": (0.5, 5.0)})
    assert informative_box(m2, separate(m2), data) is None


def test_with_bounds_keeps_the_model_and_clips_the_nominal_values():
    m = _peaks_model()
    m2 = m.with_bounds({"c": (2.0, 3.0)})
    assert m2.parameter_names == m.parameter_names and m2.output_names == m.output_names
    assert m2.nominal[m2.parameter_names.index("c")] == 2.0
    with pytest.raises(casest.ModelError, match="lower bound"):
        m.with_bounds({"c": (3.0, 2.0)})
    with pytest.raises(casest.ModelError):
        m.with_bounds({"nope": (0.0, 1.0)})


def test_gauss2_from_its_box_midpoint_reaches_the_certified_optimum_by_the_second_look():
    """NIST StRD Gauss2 from the midpoint of the protocol's box: the first estimate fits one peak
    (residuals fail), the focused look reaches the certified RSS (1.2475282092E+03, J* from it)."""
    pr = published_problem("Gauss2/mid")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = casest.estimate(pr.model, pr.data)
    assert NoteCode.FOCUSED in est.note_codes
    assert est.cost == pytest.approx(pr.J_star, abs=1e-6)
    # the labels: the two peaks by ascending centre, as NIST certifies them
    np.testing.assert_allclose(est.theta, pr.certified, rtol=1e-6)


def test_merging_terms_are_named_and_make_a_caution():
    """Two exponential terms at one rate with amplitudes that cancel: the exchange of the two
    terms is a symmetry, their rates are equal to 0.2 % and their amplitudes cancel to 0.05 %:
    a merging path, named in a MERGING note (its values from theta itself)."""
    from casest.two_stage.symmetry import merging_terms, model_symmetries

    x = ca.SX.sym("x")
    a1, b1, a2, b2 = (ca.SX.sym(n) for n in ("a1", "b1", "a2", "b2"))
    params = [casest.Parameter("a1"), casest.Parameter("b1", lb=0.01, ub=10.0, nominal=1.0),
              casest.Parameter("a2"), casest.Parameter("b2", lb=0.01, ub=10.0, nominal=1.0)]
    model = casest.Model(params, [casest.Signal("x")], {"y": a1 * ca.exp(-b1 * x) + a2 * ca.exp(-b2 * x)})
    signals = np.linspace(0.0, 5.0, 50)[:, None]
    merging = np.array([1162.0, 1.0579, -1162.6, 1.0596])
    maps = model_symmetries(model, signals, merging)
    assert any("'a1' <-> 'a2'" in m.description for m in maps)
    found = merging_terms(model, merging, maps, linear_index=[0, 2])
    assert len(found) == 1 and "b1 = 1.0579" in found[0]
    apart = np.array([2.0, 0.5, -1.0, 2.0])
    assert merging_terms(model, apart, model_symmetries(model, signals, apart), linear_index=[0, 2]) == []
