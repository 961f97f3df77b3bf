"""BOD, Puromycin (treated), Osborne 1 and Osborne 2 against their published optima (data/separable/README.md)."""

import numpy as np
import pytest

from conftest import model_file


@pytest.fixture(scope="module")
def separable():
    return model_file("separable")


@pytest.mark.parametrize("name", ["bod", "puromycin", "osborne1", "osborne2"])
def test_published_rss_to_four_digits(separable, name):
    est, rss = separable.solve(name)
    assert est.success
    published = separable.PUBLISHED[name]["rss"]
    assert float(f"{rss:.4g}") == float(f"{published:.4g}")  # equal to 4 significant digits
    assert rss == pytest.approx(published, rel=1e-4)


def test_osborne2_from_the_box_midpoint_reaches_the_published_optimum(separable):
    """Published: More, Garbow & Hillstrom (1981) problem 19, sum of squares 4.01377e-2 (to its six
    digits). From the midpoint of the protocol's box (the centres near 1000-2750 with the data in
    t = 0..6.4) the first sweep's log-uniform centres land mostly near t = 0; the focused second look
    sweeps the centres over the record (casest 0d0a90f: RSS 0.4056, CAUTION)."""
    from casest.status import NoteCode

    est, rss = separable.solve("osborne2", "mid")
    assert est.success and NoteCode.FOCUSED in est.note_codes
    assert float(f"{rss:.6g}") == separable.PUBLISHED["osborne2"]["rss"]


def test_published_parameters_and_std(separable):
    est, _ = separable.solve("puromycin")
    pub = separable.PUBLISHED["puromycin"]
    np.testing.assert_allclose([est["Vm"], est["K"]], [pub["theta"]["Vm"], pub["theta"]["K"]], rtol=5e-4)
    np.testing.assert_allclose([est.stds["Vm"], est.stds["K"]], [pub["std"]["Vm"], pub["std"]["K"]], rtol=5e-4)
    est, _ = separable.solve("bod")
    np.testing.assert_allclose([est["A"], est["k"]], [19.143, 0.5311], rtol=5e-4)


def test_separator_finds_the_linear_parameters(separable):
    import casest

    assert casest.separate(separable.bod()[0]).linear == ("A",)
    assert casest.separate(separable.puromycin()[0]).linear == ("Vm",)
    assert casest.separate(separable.osborne1()[0]).linear == ("x1", "x2", "x3")
    assert casest.separate(separable.osborne2()[0]).linear == ("x1", "x2", "x3", "x4")
