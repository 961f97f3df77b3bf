"""Likelihood-ratio confidence sets from the stage-1 sweep against a brute-force profile.

Truths: the profile deviance ``2 (J(xi2) - J_min)`` evaluated by brute force on a fine grid of
explicit candidates (``casest.sweep(..., candidates=...)``), its threshold crossings located by
linear interpolation between grid points and the profile over the other swept parameter taken
as the grid's minimum; chi-square thresholds from SciPy. Paper scalar example 1 (one swept
parameter, Eq. 30) and 2 (two, Eq. 31), simulated with seed 0; an aliased tone whose frequency
w and 2 pi - w fit the samples equally (a disjoint set, by construction).
"""

import casadi as ca
import numpy as np
import pytest
from scipy.stats import chi2

import casest
from casest.two_stage.sweep.analysis import profile_cost
from casest.two_stage.sweep.confidence import confidence_sets, likelihood_ratio_set


def _brute_profile(model, data, axes):
    """Deviance on the grid of ``axes`` (one array per swept parameter), from its own minimum."""
    mesh = np.meshgrid(*axes, indexing="ij")
    landscape = casest.sweep(model, data, candidates=np.column_stack([m.ravel() for m in mesh]))
    J = profile_cost(landscape.R, data.observed_counts()).reshape(mesh[0].shape)
    return 2 * (J - J.min())


def _crossings(values, profile, q):
    inside = np.flatnonzero(profile < q)
    lo, hi = inside[0], inside[-1]
    at = lambda i, j: values[i] + (q - profile[i]) * (values[j] - values[i]) / (profile[j] - profile[i])  # noqa: E731
    return at(lo - 1, lo), at(hi, hi + 1)


def test_one_swept_parameter_equals_the_brute_force_profile():
    m = casest.load_model_file("scalar1")
    model, data = m.model(), m.simulate(seed=0)
    b = np.linspace(0.05, 0.2, 30001)
    D = _brute_profile(model, data, [b])
    lo, hi = _crossings(b, D, chi2.ppf(0.95, 1))
    landscape = casest.sweep(model, data)
    swept = confidence_sets(model, data, 0.95, landscape=landscape).parameters["b"]
    assert swept.connected
    (a, z), (ra, rz) = swept.intervals[0], swept.resolution[0]
    assert abs(a - lo) <= ra and abs(z - hi) <= rz  # within the design's stated resolution
    refined = confidence_sets(model, data, 0.95, landscape=landscape, tol=1e-8).parameters["b"]
    np.testing.assert_allclose(refined.intervals[0], (lo, hi), atol=1e-6)
    assert max(refined.resolution[0]) <= 1e-8


@pytest.mark.parametrize("n_candidates", [2000, 9])
def test_two_swept_parameters_equal_the_brute_force_profile(n_candidates):
    """With the default design, and with one so sparse (3 x 3) that no candidate lies inside the
    set: the refinement starts from the profile's minimum between the candidates."""
    m = casest.load_model_file("scalar2")
    model, data = m.model(), m.simulate(seed=0)
    b, c = np.linspace(0.0, 0.1, 801), np.linspace(0.0, 0.45, 901)
    D = _brute_profile(model, data, [b, c])
    q = chi2.ppf(0.95, 1)
    landscape = casest.sweep(model, data, settings=casest.SweepSettings(n_candidates=n_candidates))
    coarse = confidence_sets(model, data, 0.95, landscape=landscape)
    refined = confidence_sets(model, data, 0.95, landscape=landscape, tol=1e-8)
    for name, values, profile in (("b", b, D.min(axis=1)), ("c", c, D.min(axis=0))):
        lo, hi = _crossings(values, profile, q)
        np.testing.assert_allclose(refined.parameters[name].intervals[0], (lo, hi), atol=1e-5)
        # the design's own set samples the profile from above: inside the true interval, its ends unstated
        (a, z) = coarse.parameters[name].intervals[0]
        assert lo - 1e-12 <= a <= z <= hi + 1e-12
        assert np.isnan(coarse.parameters[name].resolution[0]).all()
    # the joint set: the candidates below chi2(0.95, 2), as the deviance says
    assert coarse.threshold_joint == pytest.approx(chi2.ppf(0.95, 2))
    np.testing.assert_array_equal(coarse.inside, coarse.deviance < coarse.threshold_joint)
    assert coarse.inside.sum() < len(coarse.inside) and (coarse.inside.sum() > 0 or n_candidates == 9)


def test_an_aliased_frequency_gives_two_intervals():
    """z = a sin(w k) + c at integer k: w and 2 pi - w give the same predictions with -a, so the
    set of w is two intervals, mirror images about pi."""
    w, a, c = (ca.SX.sym(n) for n in ("w", "a", "c"))
    k = ca.SX.sym("k")
    P = casest.Parameter
    model = casest.Model([P("w", 0.3, 2 * np.pi - 0.3, 1.0), P("a"), P("c")], ["k"], {"z": a * ca.sin(w * k) + c})
    rng = np.random.default_rng(0)
    kk = np.arange(60.0)
    data = casest.Dataset(model, {"k": kk, "z": 1.5 * np.sin(1.1 * kk) + 0.2 + 0.3 * rng.standard_normal(60)})
    landscape = casest.sweep(model, data, settings=casest.SweepSettings(n_candidates=4000))
    found = confidence_sets(model, data, 0.95, landscape=landscape, tol=1e-9).parameters["w"]
    assert len(found.intervals) == 2 and not found.connected
    (a1, b1), (a2, b2) = found.intervals
    assert a1 < 1.1 < b1 < np.pi < a2 < 2 * np.pi - 1.1 < b2
    np.testing.assert_allclose([a2, b2], [2 * np.pi - b1, 2 * np.pi - a1], atol=1e-6)


def test_a_bad_level_is_refused():
    m = casest.load_model_file("scalar1")
    landscape = casest.sweep(m.model(), m.simulate(seed=0))
    with pytest.raises(casest.OptionError, match="confidence level"):
        likelihood_ratio_set(landscape, 1.2)


def test_a_gap_the_design_leaves_in_a_slanted_set_is_closed_by_the_refinement():
    """Scalar example 2, seed 7: the 44 x 44 grid has no candidate below the threshold at one c
    value inside the set (its slanted, thin part), so the design's projection of c is two
    pieces; the refinement finds the profile below the threshold in the gap and joins them,
    as the brute-force profile says (one interval)."""
    m = casest.load_model_file("scalar2")
    model, data = m.model(), m.simulate(seed=7)
    coarse = confidence_sets(model, data, 0.95)
    refined = confidence_sets(model, data, 0.95, tol=1e-9)
    assert len(coarse.parameters["c"].intervals) == 2 and refined.parameters["c"].connected
    b, c = np.linspace(0.0, 0.12, 481), np.linspace(0.0, 0.3, 1201)
    profile = _brute_profile(model, data, [b, c]).min(axis=0)
    # the grid's profile over b (steps of 2.5e-4) lies above the true one: its crossings sit up to
    # about 1e-5 inside the refined ends
    np.testing.assert_allclose(refined.parameters["c"].intervals[0], _crossings(c, profile, chi2.ppf(0.95, 1)),
                               atol=3e-5)


def test_known_noise_gives_the_cost_difference_and_equals_the_profile_interval():
    """With R known the set is where the cost difference 2 (J - J_min) < chi2(1); xi1 enters
    linearly, so the sweep's least squares is the profile over it, and the refined interval of b
    equals the profile interval re-optimising a and c (scalar example 1, R = 0.3^2 known);
    a full unknown R is refused."""
    from casest.two_stage import profile_intervals

    m = casest.load_model_file("scalar1")
    model, data = m.model(), m.simulate(seed=0)
    problem = casest.Problem(model, data, noise=casest.KnownNoise({"z": 0.09}))
    sets = confidence_sets(problem, tol=1e-10)
    est = casest.estimate(problem)
    profile = profile_intervals(problem, est.theta, est.R, est.std, names=["b"])["b"]
    np.testing.assert_allclose(sets.parameters["b"].intervals[0], (profile.lower, profile.upper), rtol=1e-6)
    unknown = confidence_sets(model, data, tol=1e-10).parameters["b"].intervals[0]
    assert abs(unknown[0] - profile.lower) > 1e-4  # the known R's set is not the unknown R's
    correlated = casest.Problem(model, data, noise=casest.CorrelatedNoise())
    with pytest.raises(casest.OptionError, match="unknown and diagonal, or known"):
        confidence_sets(correlated)
