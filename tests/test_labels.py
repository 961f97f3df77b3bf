"""Canonical labels of symmetric models: every run returns the same labels and a note names the
symmetry, from any start. Truth: data simulated with fixed seeds from the models below; the
symmetries are exact identities of the models (term exchange, sign with a shift by pi)."""

import casadi as ca
import numpy as np
import pytest

import casest
from casest.two_stage.symmetry import canonical_labels, model_symmetries
from casest.status import NoteCode

P = casest.Parameter


def _two_exponentials(nominal_rates):
    x, c = ca.SX.sym("x"), ca.SX.sym("c")
    a0, b0, a1, b1 = (ca.SX.sym(n) for n in ("a0", "b0", "a1", "b1"))
    model = casest.Model([P("c", nominal=0.0), P("a0", nominal=0.0), P("b0", 0.01, 10.0, nominal_rates[0]),
                          P("a1", nominal=0.0), P("b1", 0.01, 10.0, nominal_rates[1])], ["x"],
                         {"z": c + a0 * ca.exp(-b0 * x) + a1 * ca.exp(-b1 * x)})
    xs = np.linspace(0, 8, 120)
    z = 0.2 + 2.0 * np.exp(-0.3 * xs) - 1.5 * np.exp(-2.5 * xs) + 0.005 * np.random.default_rng(0).standard_normal(120)
    return model, casest.Dataset(model, {"x": xs, "z": z})


@pytest.mark.parametrize("nominal_rates", [(0.1, 5.0), (5.0, 0.1), (1.0, 1.2)])
def test_exchanged_terms_come_out_in_one_labelling_from_any_start(nominal_rates):
    """a0 exp(-b0 x) + a1 exp(-b1 x): the terms are exchangeable; from nominal rates on either side
    the estimate has b0 < b1 (ascending rates) and a note names the exchange."""
    model, data = _two_exponentials(nominal_rates)
    est = casest.estimate(model, data)
    assert est.values["b0"] < est.values["b1"]
    assert abs(est.values["b0"] - 0.3) < 3 * est.stds["b0"] and abs(est.values["b1"] - 2.5) < 3 * est.stds["b1"]
    labels = [n for n, c in zip(est.notes, est.note_codes) if c is NoteCode.LABELS]
    assert labels and "'a0' <-> 'a1', 'b0' <-> 'b1'" in labels[0]
    assert NoteCode.SYMMETRY not in est.note_codes  # the mirror minimum is the same solution, not a caution


@pytest.mark.parametrize("phase0", [0.3, 2.8])
def test_a_sign_and_phase_alias_comes_out_with_a_positive_amplitude(phase0):
    """a sin(w x + phi) = -a sin(w x + phi + pi): the estimate carries a > 0 and the note names the alias."""
    x, a, w, phi = (ca.SX.sym(n) for n in ("x", "a", "w", "phi"))
    model = casest.Model([P("a", nominal=0.0), P("w", 0.5, 2.0, 1.0), P("phi", -4.0, 4.0, phase0)], ["x"],
                         {"z": a * ca.sin(w * x + phi)})
    xs = np.linspace(0, 12, 150)
    z = -1.3 * np.sin(1.2 * xs + 0.5) + 0.01 * np.random.default_rng(1).standard_normal(150)  # = 1.3 sin(.. + 0.5 + pi)
    est = casest.estimate(model, casest.Dataset(model, {"x": xs, "z": z}))
    assert est.values["a"] > 0
    assert abs(np.angle(np.exp(1j * (est.values["phi"] - 0.5 - np.pi)))) < 3 * est.stds["phi"]
    labels = [n for n, c in zip(est.notes, est.note_codes) if c is NoteCode.LABELS]
    assert labels and "'a' -> -'a', 'phi' -> 'phi'" in labels[0]


def test_a_vanishing_term_does_not_fake_a_symmetry():
    """A Gaussian that underflows at every sample would pass any invariance test there; the
    moved parameters must act on the outputs for a candidate to count."""
    x, a, m, w, c = (ca.SX.sym(n) for n in ("x", "a", "m", "w", "c"))
    model = casest.Model([P("a", nominal=1.0), P("m", 0.0, 100.0, 50.0), P("w", 0.1, 1.0, 0.5), P("c", nominal=0.0)],
                         ["x"], {"z": c + a * ca.exp(-((x - m) / w) ** 2)})
    signals = np.linspace(0, 10, 40)[:, None]
    assert model_symmetries(model, signals, np.array([1.0, 90.0, 0.5, 0.2])) == ()
    maps = model_symmetries(model, signals, np.array([1.0, 5.0, 0.5, 0.2]))
    assert [m.description for m in maps] == ["'w' -> -'w'"]  # a true identity of the model ...
    theta, changed = canonical_labels(model, np.array([1.0, 5.0, 0.5, 0.2]), maps)
    assert not changed  # ... whose image lies outside the box (w >= 0.1): the labels stay


@pytest.mark.parametrize("start", [-1.0, 1.0])
def test_a_boxed_amplitude_comes_out_positive_with_the_phase_shifted(start):
    """The canonical rule: the parameter a symmetry flips comes out positive, whatever the phase's
    sign. With the amplitude boxed (it then leads the lexicographic order) and the phase in
    [-3.5, 3.5] (so that -2.6 + 2 pi lies outside), both images of
    1.3 sin(1.2 x + 0.5) inside the box have one negative parameter; the amplitude decides."""
    x, a, w, phi = (ca.SX.sym(n) for n in ("x", "a", "w", "phi"))
    model = casest.Model([P("a", -5.0, 5.0, start), P("w", 0.5, 2.0, 1.0), P("phi", -3.5, 3.5, -2.6)], ["x"],
                         {"z": a * ca.sin(w * x + phi)})
    xs = np.linspace(0, 12, 150)
    z = 1.3 * np.sin(1.2 * xs - 2.6) + 0.01 * np.random.default_rng(2).standard_normal(150)  # truth a = 1.3, phi = -2.6
    est = casest.estimate(model, casest.Dataset(model, {"x": xs, "z": z}))
    assert est.values["a"] > 0 and abs(est.values["a"] - 1.3) < 3 * est.stds["a"]
    assert abs(np.angle(np.exp(1j * (est.values["phi"] + 2.6)))) < 3 * est.stds["phi"]


@pytest.mark.parametrize("nominal_rates", [(4.0, 0.2), (0.2, 4.0)])
def test_terms_with_their_own_boxes_are_exchanged_where_each_value_fits_the_other_box(nominal_rates):
    """b0 in [0.01, 5] and b1 in [0.1, 10]: the rates 0.3 and 2.5 lie in both boxes, so the terms
    are exchangeable there and come out with ascending rates from either side; where a value
    does not fit the other box (b1 = 7 > 5), the labels stay as estimated."""
    x, c = ca.SX.sym("x"), ca.SX.sym("c")
    a0, b0, a1, b1 = (ca.SX.sym(n) for n in ("a0", "b0", "a1", "b1"))
    model = casest.Model([P("c", nominal=0.0), P("a0", nominal=0.0), P("b0", 0.01, 5.0, nominal_rates[0]),
                          P("a1", nominal=0.0), P("b1", 0.1, 10.0, nominal_rates[1])], ["x"],
                         {"z": c + a0 * ca.exp(-b0 * x) + a1 * ca.exp(-b1 * x)})
    xs = np.linspace(0, 8, 120)
    z = 0.2 + 2.0 * np.exp(-0.3 * xs) - 1.5 * np.exp(-2.5 * xs) + 0.005 * np.random.default_rng(0).standard_normal(120)
    est = casest.estimate(model, casest.Dataset(model, {"x": xs, "z": z}))
    assert est.values["b0"] < est.values["b1"]
    assert abs(est.values["b0"] - 0.3) < 3 * est.stds["b0"] and abs(est.values["b1"] - 2.5) < 3 * est.stds["b1"]
    maps = model_symmetries(model, xs[:, None], est.theta)
    outside = est.theta.copy()
    outside[[1, 2, 3, 4]] = [2.0, 0.3, -1.5, 7.0]  # b1 = 7 does not fit b0's box
    theta, changed = canonical_labels(model, outside, maps)
    assert not changed


def test_a_value_held_by_its_bound_is_not_relabelled_into_a_box_that_does_not_hold_it():
    """b0 in [0.05, 5] and b1 in [0.1, 3] (the exchange of the two terms maps the boxes' overlap
    onto itself): a point with b1 held at its lower bound 0.1 and b0 = 2 has an image inside both
    boxes (b0 = 0.1, b1 = 2) that the ascending-rate rule prefers, but there b0 = 0.1 lies
    inside b0's box: the image is not a minimum of the box problem (the bound that held the
    solution no longer acts), so the labels stay; with b1 interior the exchange is made."""
    x, c = ca.SX.sym("x"), ca.SX.sym("c")
    a0, b0, a1, b1 = (ca.SX.sym(n) for n in ("a0", "b0", "a1", "b1"))
    model = casest.Model([P("c", nominal=0.0), P("a0", nominal=0.0), P("b0", 0.05, 5.0, 1.0),
                          P("a1", nominal=0.0), P("b1", 0.1, 3.0, 1.0)], ["x"],
                         {"z": c + a0 * ca.exp(-b0 * x) + a1 * ca.exp(-b1 * x)})
    xs = np.linspace(0, 8, 120)[:, None]
    held = np.array([0.2, 2.0, 2.0, -1.5, 0.1])
    maps = model_symmetries(model, xs, held)
    assert maps  # the exchange is a symmetry there
    theta, changed = canonical_labels(model, held, maps)
    assert not changed and theta[4] == 0.1
    interior = np.array([0.2, 2.0, 2.0, -1.5, 0.3])
    theta, changed = canonical_labels(model, interior, maps)
    assert changed and theta[2] == pytest.approx(0.3) and theta[4] == pytest.approx(2.0)
