"""The residual verdict tells coloured noise from a model error and names what the model lacks.

Truths: simulated records with a fixed seed of z = a sin(c x) + b u (truth a = 1.5, c = 1.2,
b = 0.7), noise at 10 % of the output's spread; x an AR(1) signal (coefficient 0.9), u white.
The wrong models: the sensor following x by 3 samples; a missing term 0.5 u^2. The coloured
noise: AR(1) with coefficient 0.9. Holm's adjustment is checked against its definition.
"""

import numpy as np
import pytest
import casadi as ca
from scipy.signal import lfilter

import casest
from casest.estimation.diagnostics import ALPHA, ResidualCheck, family_adjusted
from casest.estimation.independence import independence_test, prewhitener, step_test
from casest.status import CheckCode, DiagnosisCode, TrustCode


def _model():
    a, b, c, x, u = (ca.SX.sym(n) for n in ("a", "b", "c", "x", "u"))
    return casest.Model([casest.Parameter("a", lb=-5, ub=5), casest.Parameter("b"), casest.Parameter("c", lb=0.1, ub=3)],
                        ["x", "u"], {"z": a * ca.sin(c * x) + b * u}, name="verdict_demo")


def _record(seed, lag=0, term=0.0, rho=0.0, N=1000):
    rng = np.random.default_rng(seed)
    x = lfilter([1], [1, -0.9], rng.standard_normal(N + 10)) * 0.5
    u = rng.standard_normal(N)
    seen = x[10 - lag:N + 10 - lag]
    z = 1.5 * np.sin(1.2 * seen) + 0.7 * u + term * u**2
    noise = lfilter([1], [1, -rho], rng.standard_normal(N)) * np.sqrt(1 - rho**2)
    z = z + 0.1 * np.std(z) * noise
    return casest.Dataset(_model(), {"x": x[10:N + 10], "u": u, "z": z})


def test_holm_adjustment_is_the_step_down_definition():
    ps = [0.01, 0.04, 0.0001, 0.5]
    checks = [ResidualCheck(CheckCode.WHITENESS, "z", 0.0, 1.0, p) for p in ps]
    adjusted = [c.adjusted_p for c in family_adjusted(checks)]
    # sorted p: 1e-4 (x4), 0.01 (x3), 0.04 (x2), 0.5 (x1), running maximum
    assert adjusted == pytest.approx([0.03, 0.08, 0.0004, 0.5])


def test_independence_and_step_tests_hold_their_level_on_coloured_noise():
    """400 AR(1) records (coefficient 0.9) against an AR(1) signal: the rate at p < 0.05 within
    three binomial std of 5 %."""
    rng = np.random.default_rng(7)
    p_cross, p_step = [], []
    for _ in range(400):
        r = lfilter([1], [1, -0.9], rng.standard_normal(500))
        x = lfilter([1], [1, -0.95], rng.standard_normal(500))
        w = prewhitener(r)
        p_cross.append(independence_test(w.apply(r), w.apply(x), np.arange(-5, 6)).p_value)
        p_step.append(step_test(r, w).p_value)
    band = 3 * np.sqrt(0.05 * 0.95 / 400)
    assert abs(np.mean(np.array(p_cross) < 0.05) - 0.05) < band
    assert np.mean(np.array(p_step) < 0.05) < 0.05 + band


def test_the_right_model_with_white_noise_is_trusted():
    est = casest.estimate(_model(), _record(1))
    assert est.conclusion()[0] is TrustCode.TRUSTED and est.diagnosis is None
    assert {c.code for c in est.residual_checks} >= {CheckCode.WHITENESS, CheckCode.CROSS_CORRELATION, CheckCode.STEP}


def test_coloured_noise_keeps_the_estimate_and_reports_colored_std():
    est = casest.estimate(_model(), _record(2, rho=0.9))
    code, reason = est.conclusion()
    assert code is TrustCode.COLOURED_NOISE and est.diagnosis is None
    choice = est.std_choice()
    # a and c act through the slow signal x: their std grow; b acts through the white u: it does not
    assert choice.kind == "colored" and np.all(choice.std[[0, 2]] > 1.5 * est.std[[0, 2]])
    assert choice.std[1] == pytest.approx(est.std[1], rel=0.3)
    assert "colored-residual standard deviation" in est.report().split("[[Parameters]]")[1].splitlines()[0]
    truth = np.array([1.5, 0.7, 1.2])
    assert np.all(np.abs(est.theta - truth) < 3 * choice.std)  # the estimate stands


def test_a_lagged_signal_is_a_model_error_diagnosed_as_a_lag(tmp_path):
    model, data = _model(), _record(3, lag=3)
    est = casest.estimate(model, data)
    assert est.conclusion()[0] is TrustCode.MODEL_ERROR
    d = est.diagnosis
    assert d is not None and d.code is DiagnosisCode.LAG and d.signals == ("x",)
    assert abs(d.value - 3) < 3 * d.std and d.rms_after[0] < 0.5 * d.rms_before[0]
    loaded = casest.Estimate.from_json(est.to_json(tmp_path / "lag.json"))
    assert loaded.diagnosis == d or loaded.diagnosis.to_dict() == d.to_dict()
    refit = casest.refit(est, model, data)
    assert refit.parameter == "delay_x" and abs(refit.value - 3) < 3 * refit.std
    assert refit.estimate.conclusion()[0] in (TrustCode.TRUSTED, TrustCode.LOCAL)


def test_a_missing_term_is_a_model_error_and_is_named():
    est = casest.estimate(_model(), _record(4, term=0.5))
    assert est.conclusion()[0] is TrustCode.MODEL_ERROR
    assert est.diagnosis is not None and est.diagnosis.code is DiagnosisCode.TERM and est.diagnosis.term == "u^2"
    assert abs(est.diagnosis.value - 0.5) < 3 * est.diagnosis.std


def test_the_report_summarises_the_checks_one_line_per_output():
    est = casest.estimate(_model(), _record(5, rho=0.9))
    section = est.report().split("[[Residual checks]]")[1]
    assert f"held at {ALPHA:g} by Holm" in section.splitlines()[0]
    assert section.splitlines()[1].strip().startswith("z: ") and "failed; worst" in section.splitlines()[1]
    html = est.to_html()
    assert "<details><summary>every test" in html


def test_regression_names_a_missing_square_and_trusts_the_right_terms():
    """Truth: y = 1 + 2 a + 0.5 b + 0.3 a^2 + white noise of std 0.1 (a, b standard normal, N = 500)."""
    import casadi as ca

    rng = np.random.default_rng(0)
    a, b = rng.standard_normal(500), rng.standard_normal(500)
    A, B = ca.SX.sym("a"), ca.SX.sym("b")
    y = 1 + 2 * a + 0.5 * b + 0.3 * a**2 + 0.1 * rng.standard_normal(500)
    fit = casest.regress(y, {"bias": 1, "a": A, "b": B}, {"a": a, "b": b})
    assert fit.conclusion()[0] is TrustCode.MODEL_ERROR
    assert fit.diagnosis.code is DiagnosisCode.TERM and fit.diagnosis.term == "a^2"
    assert abs(fit.diagnosis.value - 0.3) < 3 * fit.diagnosis.std
    back = casest.Regression.from_json(fit.to_json())
    assert back.residual_checks == fit.residual_checks and back.conclusion() == fit.conclusion()
    right = casest.regress(y, {"bias": 1, "a": A, "b": B, "a2": A**2}, {"a": a, "b": b})
    assert right.conclusion()[0] is TrustCode.LOCAL and right.diagnosis is None


def test_many_signals_do_not_raise_false_alarms():
    """The right model with white noise and ten measured signals (eight not in the model), 30 seeds
    of N = 200: each fit's family of 23 tests is held at ALPHA = 1e-3, so more than one fit not
    trusted (probability below 5e-4 with a correct family) says the control is broken."""
    model = _model()
    alarms = 0
    for seed in range(30):
        rng = np.random.default_rng([seed, 66])
        x = lfilter([1], [1, -0.5], rng.standard_normal(200)) * 0.5
        u = rng.standard_normal(200)
        z = 1.5 * np.sin(1.2 * x) + 0.7 * u
        columns = {"x": x, "u": u, "z": z + 0.1 * np.std(z) * rng.standard_normal(200)}
        columns.update({f"w{k}": lfilter([1], [1, -0.5], rng.standard_normal(200)) for k in range(8)})
        wide = casest.Model(list(model.parameters), ["x", "u"] + [f"w{k}" for k in range(8)],
                            {"z": model.h[0]}, name="wide")
        est = casest.estimate(wide, casest.Dataset(wide, columns))
        assert len(est.residual_checks) == 23  # whiteness, 11 trends, 10 cross-correlations, step
        alarms += est.conclusion()[0] is not TrustCode.TRUSTED
    assert alarms <= 1
