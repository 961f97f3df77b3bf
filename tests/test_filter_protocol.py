"""The filter protocol: the Kalman filter, the EKF/IEKF and the UKF offer one step API
(``x``, ``P``, ``predict``, ``update``, ``predict_ahead``, ``filter`` returning a FilterResult);
the filters on a dynamic model share one implementation of the record pass, ``reset`` and the
prediction ahead (``ModelFilter``), each supplying only its own time and measurement update and
its compiled pass.

Truth: the short-period model file at its true parameters (``models/short_period.py``); the
prediction ahead is checked against the filter's own time update repeated (the summary's
Eq. 2.12-2.13), exactly.
"""

import numpy as np
import pytest

import casest
from casest.filters import ModelFilter, StateFilter


@pytest.fixture(scope="module")
def short_period():
    m = casest.load_model_file("short_period")
    model, data = m.model(), m.simulate(seed=0)
    R = [m.NOISE_STD[n] ** 2 for n in model.output_names]
    return m, model, data, R


def _filters(short_period):
    m, model, data, R = short_period
    P0 = np.eye(2) * 1e-6
    return [casest.ExtendedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, P0),
            casest.ExtendedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, P0, iterated=True),
            casest.UnscentedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, P0)]


def test_every_filter_implements_the_protocol(short_period):
    kf = casest.KalmanFilter(np.eye(1), np.eye(1), np.eye(1) * 1e-3, np.eye(1), np.zeros(1), np.eye(1))
    for flt in [kf] + _filters(short_period):
        assert isinstance(flt, StateFilter), type(flt).__name__
    result = kf.filter(np.ones((5, 1)))
    assert isinstance(result, casest.FilterResult)


def test_the_model_filters_share_one_record_pass():
    """No copies: the record pass, reset and the prediction ahead are ModelFilter's own."""
    for cls in (casest.ExtendedKalmanFilter, casest.UnscentedKalmanFilter):
        assert issubclass(cls, ModelFilter)
        for name in ("filter", "reset", "predict_ahead"):
            assert getattr(cls, name) is getattr(ModelFilter, name), (cls.__name__, name)


@pytest.mark.parametrize("which", [0, 1, 2], ids=["ekf", "iekf", "ukf"])
def test_compiled_and_stepwise_passes_agree_and_predict_ahead_repeats_the_time_update(short_period, which):
    m, model, data, R = short_period
    flt = _filters(short_period)[which]
    compiled = flt.filter(data, compiled=True)
    stepwise = flt.filter(data, compiled=False)
    assert isinstance(compiled, casest.FilterResult)
    np.testing.assert_allclose(compiled.x_filtered, stepwise.x_filtered, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(compiled.P_filtered, stepwise.P_filtered, rtol=1e-9, atol=1e-15)
    dt = float(data.signals[1, 0] - data.signals[0, 0])
    u = data.signals[-1, 1:]
    x_ahead, P_ahead = flt.predict_ahead(3, dt, u)
    x_kept, P_kept = flt.x.copy(), flt.P.copy()
    np.testing.assert_array_equal(flt.x, x_kept)  # the state is left as it was
    for i in range(3):
        Ua, Ub = model.interval_input_values(np.vstack([u, u]))
        x, P, _ = flt.predict(dt, Ua[0], Ub[0], u)
        np.testing.assert_allclose(x_ahead[i], x, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(P_ahead[i], P, rtol=1e-12, atol=1e-18)
    flt.reset(x_kept, P_kept)
    np.testing.assert_array_equal(flt.x, x_kept)
