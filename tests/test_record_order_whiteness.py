"""Residual whiteness in the record's own order for static models built from plain arrays.

Truth: a simulated magnetometer-like static calibration (a gain and an offset per sample of a
slowly turning field) whose measurements hold a step of 3 noise std from 60 % of the record on
(a magnet removed): white noise in any order passes, the step does not; the record is built
from plain arrays (not flagged ``time_ordered``).
"""

import casadi as ca
import numpy as np

import casest
from casest.status import CheckCode, TrustCode


def _calibration(step: float, seed: int = 3):
    g, o, u = ca.SX.sym("g"), ca.SX.sym("o"), ca.SX.sym("u")
    model = casest.Model([casest.Parameter("g", 0.5, 2.0, 1.0), casest.Parameter("o", -5.0, 5.0, 0.0)],
                         [casest.Signal("u")], {"z": g * u + o}, name="static_calibration")
    rng = np.random.default_rng(seed)
    N = 400
    field = 40.0 * np.sin(np.linspace(0.0, 6 * np.pi, N))  # a field turning while the sensor records
    z = 1.05 * field + 0.8 + 0.86 * rng.standard_normal(N)
    z[int(0.6 * N):] += step * 0.86
    return model, casest.Dataset(model, {"u": field, "z": z})


def test_a_step_in_the_record_is_seen_in_the_records_order():
    model, data = _calibration(step=3.0)
    assert not data.time_ordered
    est = casest.estimate(model, data)
    failed = [c for c in est.residual_checks if not c.passed]
    assert any(c.order == "record" for c in failed), [c.describe() for c in est.residual_checks]
    # a change of level in time: the residuals depend on time, a model error (the step test names the sample)
    assert est.conclusion()[0] is TrustCode.MODEL_ERROR
    assert any(c.code is CheckCode.STEP and abs(c.lag - 240) <= 12 for c in failed)


def test_white_noise_in_the_record_passes_both_orders():
    model, data = _calibration(step=0.0)
    est = casest.estimate(model, data)
    orders = sorted(c.order for c in est.residual_checks if c.code in (CheckCode.WHITENESS, CheckCode.TREND))
    assert orders == ["fitted value", "record"] and all(c.passed for c in est.residual_checks)
