"""Residual structure along each signal of a static model: the whiteness test in the order of
every measured signal.

Truth: simulated two-signal calibrations (fixed seeds, samples in random order, as a test bench
records them) of y = a x1 + b x2 with white noise of std 0.05: the true model passes every
residual test; a model that leaves out a term in x2 alone (0.2 sin(3 x2), far below the fitted
values' spread) is caught in the order of x2, and the estimate is then not trusted.
"""

import casadi as ca
import numpy as np

import casest
from casest.status import CheckCode, TrustCode


def _calibration(extra: float, seed: int = 4):
    rng = np.random.default_rng(seed)
    N = 400
    x1, x2 = rng.uniform(-2, 2, N), rng.uniform(-2, 2, N)
    y = 1.5 * x1 - 0.7 * x2 + extra * np.sin(3 * x2) + 0.05 * rng.standard_normal(N)
    s1, s2 = ca.SX.sym("x1"), ca.SX.sym("x2")
    a, b = ca.SX.sym("a"), ca.SX.sym("b")
    model = casest.Model([casest.Parameter("a", -10, 10, 1.0), casest.Parameter("b", -10, 10, 1.0)],
                         [casest.Signal("x1"), casest.Signal("x2")], {"y": a * s1 + b * s2}, name="two_axis")
    return model, casest.Dataset(model, {"x1": x1, "x2": x2, "y": y})


def test_the_true_model_passes_in_every_order():
    model, data = _calibration(0.0)
    est = casest.estimate(model, data)
    orders = {c.order for c in est.residual_checks if c.code in (CheckCode.WHITENESS, CheckCode.TREND)}
    assert {"fitted value", "record", "signal x1", "signal x2"} <= orders
    assert all(c.passed for c in est.residual_checks), [c.describe() for c in est.residual_checks]
    assert est.conclusion()[0] is TrustCode.TRUSTED


def test_a_term_missing_in_one_signal_is_caught_along_that_signal():
    model, data = _calibration(0.2)
    est = casest.estimate(model, data)
    failed = [c for c in est.residual_checks if not c.passed]
    assert any(c.order == "signal x2" for c in failed), [c.describe() for c in est.residual_checks]
    assert est.conclusion()[0] is TrustCode.MODEL_ERROR
    assert "signal x2" in est.report()
