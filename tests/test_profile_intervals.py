"""Profile-likelihood intervals by re-optimisation against lmfit's ``conf_interval``.

Truth: lmfit 1.x ``conf_interval`` (its own re-optimisation along each parameter with
``leastsq`` and root finding to 5e-5 relative), given the same statistic as casest: the
likelihood ratio of one output with R unknown, ``N ln(chi2_new / chi2_best)`` against
chi-square with one degree of freedom (a ``prob_func``). Paper scalar examples 1 and 2 (seed 0):
every end equal to 1e-4 relative. A dynamic model (``models/short_period.py``): the deviance at
each end equals the threshold (the problem's own profile cost) and the interval holds the estimate.
"""

import numpy as np
import pytest
from scipy.stats import chi2

import casest
from casest.two_stage.profile import profile_intervals

def _lmfit_intervals(model, data, theta, level):
    lmfit = pytest.importorskip("lmfit")
    params = lmfit.Parameters()
    for p, v in zip(model.parameters, theta):
        params.add(p.name, value=v, min=p.lb, max=p.ub)
    names, z = model.parameter_names, data.outputs[:, 0]

    def residual(pars):
        return z - model.predict(np.array([pars[n].value for n in names]), data.signals)[:, 0]

    minimizer = lmfit.Minimizer(residual, params)
    result = minimizer.minimize(method="leastsq", xtol=1e-12, ftol=1e-12)

    def likelihood_ratio(best, new):
        return chi2.cdf(best.ndata * np.log(new.chisqr / best.chisqr), best.nvarys - new.nvarys)

    ci = lmfit.conf_interval(minimizer, result, sigmas=[level], prob_func=likelihood_ratio)
    return {n: [v for prob, v in ci[n] if abs(prob - level) < 1e-12] for n in names}


@pytest.mark.parametrize("name", ["scalar1", "scalar2"])
def test_profile_intervals_equal_lmfits_conf_interval(name):
    m = casest.load_model_file(name)
    model, data = m.model(), m.simulate(seed=0)
    est = casest.estimate(model, data)
    ours = profile_intervals(casest.Problem(model, data), est.theta, est.R, est.std, level=0.95)
    theirs = _lmfit_intervals(model, data, est.theta, 0.95)
    for p in model.parameter_names:
        np.testing.assert_allclose([ours[p].lower, ours[p].upper], theirs[p], rtol=1e-4)
        assert ours[p].lower < ours[p].estimate < ours[p].upper and ours[p].at_bound == (False, False)


def test_a_dynamic_models_ends_sit_on_the_threshold():
    m = casest.load_model_file("short_period")
    model, data = m.model(), m.simulate(seed=0)
    problem = casest.Problem(model, data)
    est = casest.estimate(problem)
    name = model.parameter_names[0]
    found = profile_intervals(problem, est.theta, est.R, est.std, level=0.9, names=[name])[name]
    assert found.lower < est.theta[0] < found.upper
    q = chi2.ppf(0.9, 1)
    J_hat = problem.profile_cost(est.theta)
    for end in (found.lower, found.upper):  # the profile there, by a constrained estimate of the others
        fixed = casest.Problem(model, data, fixed={name: end})
        held = casest.estimate(fixed)
        J = fixed.profile_cost(held.theta)
        assert 2 * (J - J_hat) == pytest.approx(q, rel=1e-3)


def test_what_it_refuses():
    m = casest.load_model_file("scalar1")
    model, data = m.model(), m.simulate(seed=0)
    est = casest.estimate(model, data)
    problem = casest.Problem(model, data)
    with pytest.raises(casest.OptionError, match="no parameter"):
        profile_intervals(problem, est.theta, est.R, names=["zeta"])
    with pytest.raises(casest.OptionError, match="confidence level"):
        profile_intervals(problem, est.theta, est.R, level=0)


def test_the_estimate_carries_its_intervals_into_the_report_and_the_file():
    """Scalar example 1 with b = 0.01 in its box [0, 0.2] (half a std above the bound): its profile
    interval reaches the bound and is asymmetric, so the report shows it beside the std; a and c
    (within 10 % of +-z std) are named as such; the file keeps the intervals."""
    from casest.two_stage import with_profile_intervals

    m = casest.load_model_file("scalar1")
    model = m.model()
    eta = np.linspace(1.0, 10.0, 100)
    rng = np.random.default_rng(3)
    z = model.predict(model.vector(dict(m.TRUTH, b=0.01)), eta[:, None])[:, 0] + 0.3 * rng.standard_normal(100)
    problem = casest.Problem(model, casest.Dataset(model, {"eta": eta, "z": z}))
    est = with_profile_intervals(casest.estimate(problem), problem)
    b = {i.name: i for i in est.intervals}["b"]
    assert b.at_bound == (True, False) and b.lower == 0.0
    report = est.report()
    assert "[[Profile intervals]]" in report and "b: [0 (bound)," in report and "as value +/- z std: a, c" in report
    assert "b: [0, " in report and "(likelihood-ratio set from the sweep)" in report  # the sweep's set, at the bound too
    back = casest.Estimate.from_json(est.to_json())
    assert back.intervals == est.intervals and back.likelihood_sets == est.likelihood_sets
    assert "[[Profile intervals]]" not in casest.estimate(problem).report()
    pytest.importorskip("pandas")
    frame = est.parameters_frame()
    assert frame.loc["b", "interval_lower"] == 0.0 and frame.loc["b", "interval_upper"] == b.upper


def test_a_set_in_pieces_is_reported():
    """The aliased tone (w and 2 pi - w fit alike): the sweep's 95 % set of w is two intervals,
    which the report shows beside the std."""
    import sys, os

    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts", "examples"))
    from confidence_sets_figure import aliased_tone
    from casest.two_stage import with_profile_intervals

    model, data = aliased_tone()
    problem = casest.Problem(model, data)
    est = with_profile_intervals(casest.estimate(problem, sweep_settings=casest.SweepSettings(n_candidates=4000)),
                                 problem)
    w = {s.name: s for s in est.likelihood_sets}["w"]
    assert len(w.intervals) == 2
    assert "(likelihood-ratio set from the sweep, 2 pieces)" in est.report()


def test_multiple_shooting_is_refused_with_the_fix():
    m = casest.load_model_file("short_period")
    model, data = m.model(), m.simulate(seed=0)
    problem = casest.Problem(model, data)
    est = casest.estimate(problem)
    with pytest.raises(casest.OptionError, match="shooting='single'"):
        profile_intervals(problem, est.theta, est.R, names=[model.parameter_names[0]],
                          settings=casest.SolverSettings(shooting="multiple"))
