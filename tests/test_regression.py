"""Equation error (casest.regress) and stepwise model-structure selection (casest.stepwise).

Independent truths: scipy.stats.linregress for a single regressor (slope, its std, R^2); the
F statistic from the sums of squares of two separate numpy fits; PRESS by refitting without each
sample in turn; the coloured-residual std against the Monte-Carlo spread of 300 simulated AR(1)
records (seeded); the true structure of a simulated pitching-moment model for stepwise.
"""

import casadi as ca
import numpy as np
import pytest
from scipy import stats

import casest
from casest.errors import DataError, OptionError

alpha, q, de, V = (ca.SX.sym(n) for n in ("alpha", "q", "de", "V"))


def _record(n=400, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.02
    return {"alpha": 0.05 * np.sin(1.3 * t) + 0.01 * rng.standard_normal(n),
            "q": 0.1 * np.cos(0.9 * t) + 0.02 * rng.standard_normal(n),
            "de": 0.03 * np.sign(np.sin(0.5 * t)) + 0.005 * rng.standard_normal(n),
            "V": 25.0 + rng.standard_normal(n)}


def test_one_regressor_matches_scipy_linregress():
    data = _record()
    y = 0.3 - 1.7 * data["alpha"] + 0.01 * np.random.default_rng(1).standard_normal(400)
    fit = casest.regress(y, {"bias": 1, "alpha": alpha}, data, colored=False)
    ref = stats.linregress(data["alpha"], y)
    np.testing.assert_allclose(fit.theta, [ref.intercept, ref.slope], rtol=1e-10)
    np.testing.assert_allclose(fit.std_white[1], ref.stderr, rtol=1e-10)
    np.testing.assert_allclose(fit.r_squared, ref.rvalue**2, rtol=1e-10)
    np.testing.assert_allclose(fit.t_values[1], ref.slope / ref.stderr, rtol=1e-10)


def test_f_statistic_press_and_pse_from_their_definitions():
    data = _record()
    rng = np.random.default_rng(2)
    y = 0.1 + 2.0 * data["alpha"] - 0.5 * data["q"] + 0.02 * rng.standard_normal(400)
    terms = {"bias": 1, "alpha": alpha, "q": q, "alpha_q": alpha * q}
    fit = casest.regress(y, terms, data, colored=False)
    X = np.column_stack([np.ones(400), data["alpha"], data["q"], data["alpha"] * data["q"]])
    sse = np.sum((y - X @ np.linalg.lstsq(X, y, rcond=None)[0]) ** 2)
    sst = np.sum((y - y.mean()) ** 2)
    assert fit.f_statistic == pytest.approx(((sst - sse) / 3) / (sse / 396), rel=1e-9)
    loo = [y[i] - X[i] @ np.linalg.lstsq(np.delete(X, i, 0), np.delete(y, i), rcond=None)[0] for i in range(400)]
    assert fit.press == pytest.approx(np.sum(np.square(loo)), rel=1e-8)
    assert fit.pse == pytest.approx(sse / 400 + (sst / 400) * 4 / 400, rel=1e-12)


def test_weighted_least_squares_equals_ordinary_least_squares_on_scaled_rows():
    data = _record()
    rng = np.random.default_rng(3)
    sigma = np.where(np.arange(400) < 200, 0.01, 0.05)
    y = 0.2 + 1.1 * data["alpha"] + sigma * rng.standard_normal(400)
    fit = casest.regress(y, {"bias": 1, "alpha": alpha}, data, weights=1 / sigma**2, colored=False)
    Xs = np.column_stack([np.ones(400), data["alpha"]]) / sigma[:, None]
    np.testing.assert_allclose(fit.theta, np.linalg.lstsq(Xs, y / sigma, rcond=None)[0], rtol=1e-10)


def test_coloured_residual_std_matches_the_monte_carlo_spread():
    """AR(1) residuals (phi = 0.9) on 2000-sample records: the white-residual std is too small by about sqrt((1 + phi) /
    (1 - phi)) for slowly varying regressors (0.23-0.24 of the spread); the coloured one is within
    25 % of it (0.88-0.91; Bartlett-weighted lags are biased low on short records)."""
    n = 2000
    base = _record(n, seed=4)
    terms = {"bias": 1, "alpha": alpha, "de": de}
    estimates, std_c, std_w = [], [], []
    for run in range(300):
        rng = np.random.default_rng(100 + run)
        w = rng.standard_normal(n) * 0.01
        e = np.empty(n)
        e[0] = w[0] / np.sqrt(1 - 0.81)
        for k in range(1, n):
            e[k] = 0.9 * e[k - 1] + w[k]
        fit = casest.regress(0.1 + 2.0 * base["alpha"] - 0.8 * base["de"] + e, terms, base)
        estimates.append(fit.theta)
        std_c.append(fit.std)
        std_w.append(fit.std_white)
    spread = np.std(estimates, axis=0, ddof=1)
    ratio_c, ratio_w = np.mean(std_c, axis=0) / spread, np.mean(std_w, axis=0) / spread
    assert np.all(np.abs(ratio_c - 1) < 0.25), ratio_c
    assert np.all(ratio_w < 0.6), ratio_w


def test_terms_are_expressions_of_the_columns_and_mistakes_are_named():
    data = _record()
    fit = casest.regress("q", {"bias": 1, "q_hat": q * 0.5 / (2 * V)}, {**data}, colored=False)
    assert fit.names == ("bias", "q_hat") and fit.theta[1] == pytest.approx(4 * 25.0, rel=0.05)
    with pytest.raises(DataError, match=r"the terms use \['alpa'\].*did you mean 'alpha'"):
        casest.regress(data["q"], {"a": ca.SX.sym("alpa")}, data)
    with pytest.raises(DataError, match="y must have shape"):
        casest.regress(np.ones(3), {"a": alpha}, data)
    with pytest.raises(DataError, match=r"\['alpha2'\] are linear combinations"):
        casest.regress(data["q"], {"alpha": alpha, "alpha2": 2 * alpha}, data)
    with pytest.raises(DataError, match="holds NaN"):
        casest.regress(data["q"], {"a": alpha}, {**data, "alpha": np.full(400, np.nan)})
    with pytest.raises(OptionError, match="non-empty mapping"):
        casest.regress(data["q"], {}, data)


def test_symbols_made_afresh_are_matched_to_the_columns_by_name():
    """Truth: cm = alpha^2 + 0.1 q exactly (no noise): the fit with alpha built twice, as SX and as
    MX, gives the coefficients 1 and 0.1; SX and MX mixed are refused by name."""
    alpha = np.linspace(0.0, 1.0, 50)
    q = np.cos(np.arange(50.0))
    data = {"alpha": alpha, "q": q, "cm": alpha**2 + 0.1 * q}
    for kind in (ca.SX, ca.MX):
        fit = casest.regress("cm", {"1": 1, "q": kind.sym("q"), "alpha2": kind.sym("alpha") ** 2,
                                    "alpha": kind.sym("alpha")}, data, colored=False)
        np.testing.assert_allclose(fit.theta, [0.0, 0.1, 1.0, 0.0], atol=1e-9)
    with pytest.raises(OptionError, match="SX expression and others are MX"):
        casest.regress("cm", {"alpha": ca.SX.sym("alpha"), "alpha2": ca.MX.sym("alpha") ** 2}, data)


def test_stepwise_recovers_the_true_pitching_moment_structure():
    """Cm = Cm0 + Cm_alpha alpha + Cm_q q_hat + Cm_de de + noise, among nine candidates."""
    rng = np.random.default_rng(7)
    n = 1500
    t = np.arange(n) * 0.02
    data = {"alpha": 0.08 * np.sin(0.7 * t) + 0.03 * np.sin(2.9 * t + 1),
            "q": 0.2 * np.cos(1.1 * t) + 0.05 * rng.standard_normal(n),
            "de": 0.05 * np.sign(np.sin(0.45 * t + 0.3)) + 0.01 * rng.standard_normal(n),
            "V": 24.0 + 2.0 * np.sin(0.1 * t)}
    q_hat = data["q"] * 0.5 / (2 * data["V"])
    cm = 0.02 - 0.9 * data["alpha"] - 15.0 * q_hat - 1.2 * data["de"] + 0.002 * rng.standard_normal(n)
    candidates = {"bias": 1, "alpha": alpha, "q_hat": q * 0.5 / (2 * V), "de": de, "alpha2": alpha**2,
                  "alpha_de": alpha * de, "alpha_q": alpha * q * 0.5 / (2 * V), "de2": de**2, "V": V}
    result = casest.stepwise(cm, candidates, data, always=["bias"])
    assert set(result.selected) == {"bias", "alpha", "q_hat", "de"}, result.report()
    truth = {"bias": 0.02, "alpha": -0.9, "q_hat": -15.0, "de": -1.2}
    z = [(result.fit.theta[i] - truth[name]) / result.fit.std[i] for i, name in enumerate(result.selected)]
    assert np.all(np.abs(z) < 3), z
    assert result.steps[0].action.startswith("+") and "stopped" not in result.report()[:0]


def test_stepwise_refuses_thresholds_that_would_cycle():
    data = _record()
    with pytest.raises(OptionError, match="f_out <= f_in"):
        casest.stepwise(data["q"], {"bias": 1, "a": alpha}, data, f_in=2.0, f_out=5.0)
    with pytest.raises(OptionError, match="always names"):
        casest.stepwise(data["q"], {"bias": 1, "a": alpha}, data, always=["intercept"])


def test_the_pages_of_a_regression_and_a_stepwise_carry_the_fit_statistics():
    """The HTML page lists what the report's table gives: N, R^2 (scipy.stats.linregress's r^2), F,
    the fit error's std s = sqrt(s^2), PSE and PRESS; a stepwise page adds its steps and stop."""
    import html
    data = _record()
    y = 0.3 - 1.7 * data["alpha"] + 0.01 * np.random.default_rng(1).standard_normal(400)
    fit = casest.regress(y, {"bias": 1, "alpha": alpha}, data, colored=False)
    page = html.unescape(fit.to_html())
    ref = stats.linregress(data["alpha"], y)
    assert "id='fit_statistics'" in page and f"{100 * ref.rvalue**2:.2f} %" in page
    for shown in (f"{fit.f_statistic:.4g}", f"{np.sqrt(fit.s2):.4g}", f"{fit.pse:.4g}", f"{fit.press:.4g}"):
        assert f"<td>{shown}" in page, shown
    chosen = casest.stepwise(y, {"bias": 1, "alpha": alpha, "q": q}, data, always=["bias"])
    page = html.unescape(chosen.to_html())
    assert f"<td>{chosen.stopped}</td>" in page and f"{100 * chosen.fit.r_squared:.2f} %" in page
