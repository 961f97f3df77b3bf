"""Recursive estimation: RLS against batch least squares, the iterated EKF against the batch estimate."""

import numpy as np
import pytest

import casest
from casest.recursive.least_squares import ParameterEKF, RecursiveLeastSquares
from casest.two_stage import seed_from_stage1
from casest.two_stage.solve import weighted_linear_parameters

from conftest import model_file


@pytest.fixture(scope="module")
def magnetometer():
    return model_file("magnetometer")


@pytest.mark.parametrize("inversion", ["parameters", "measurements"])
def test_rls_equals_batch_least_squares(magnetometer, inversion):
    """At fixed xi2 the magnetometer is linear in xi1 = [lambda, n]: RLS must equal the batch WLS to 1e-10."""
    model = magnetometer.model()
    data = magnetometer.simulate(2, n=300)
    part = casest.separate(model)
    xi2 = model.vector(magnetometer.TRUTH)[list(part.nonlinear_index)]
    weights = np.array([0.04, 0.05, 0.03])
    rls = RecursiveLeastSquares(model, part, xi2, weights, inversion=inversion)
    xi1 = rls.run(data)
    batch = weighted_linear_parameters(model, part, data, xi2, weights)
    np.testing.assert_allclose(xi1, batch, rtol=1e-10, atol=1e-12)


def test_rls_rejects_unknown_inversion(magnetometer):
    model = magnetometer.model()
    with pytest.raises(ValueError, match="inversion"):
        RecursiveLeastSquares(model, casest.separate(model), np.zeros(6), inversion="both")


def test_iterated_ekf_matches_batch(magnetometer):
    """Seeded by the batch estimate on a 100-sample window, run over the rest (simulated truth)."""
    model = magnetometer.model()
    data = magnetometer.simulate(5, n=1500)
    first, rest = data.subset(slice(0, 100)), data.subset(slice(100, None))
    ekf = ParameterEKF.from_estimate(model, casest.estimate(model, first))
    hist = ekf.run(rest, record_every=100)
    assert hist.theta.shape[1] == model.n_parameters and hist.index[-1] == rest.n_samples
    truth = model.vector(magnetometer.TRUTH)
    assert np.all(np.abs(ekf.theta - truth) < 3 * ekf.std)
    batch = casest.estimate(model, data)
    ratio = ekf.std / batch.std
    assert np.all((ratio > 0.8) & (ratio < 1.2)), ratio  # covariance within 20 % per std
    assert np.all(np.abs(ekf.theta - batch.theta) < 0.2 * batch.std)


def test_plain_ekf_and_chunks_and_stage1_seed(magnetometer):
    model = magnetometer.model()
    data = magnetometer.simulate(6, n=800)
    first, rest = data.subset(slice(0, 80)), data.subset(slice(80, None))
    theta0, P0, R, land = seed_from_stage1(model, first)
    assert land.n_samples == 80 and P0.shape == (12, 12)
    R_true = np.full(3, magnetometer.NOISE_STD**2)
    truth = model.vector(magnetometer.TRUTH)
    for iterated, chunk in ((False, 1), (True, 20)):
        ekf = ParameterEKF(model, theta0, P0, R_true, iterated=iterated)
        ekf.run(rest, chunk=chunk)
        assert np.all(np.abs(ekf.theta - truth) < 3 * ekf.std), (iterated, chunk)


def test_random_walk_process_noise_keeps_the_filter_open(magnetometer):
    model = magnetometer.model()
    data = magnetometer.simulate(7, n=400)
    est = casest.estimate(model, data.subset(slice(0, 100)))
    still = ParameterEKF.from_estimate(model, est)
    drifting = ParameterEKF.from_estimate(model, est, process_noise=np.full(12, 1e-8))
    still.run(data.subset(slice(100, None)))
    drifting.run(data.subset(slice(100, None)))
    assert np.all(drifting.std > still.std)


def test_parameter_ekf_skips_missing_channels(magnetometer):
    """A NaN channel is skipped: the update equals the one on the measured channels alone."""
    model = magnetometer.model()
    data = magnetometer.simulate(8, n=200)
    theta0, P0, R, _ = seed_from_stage1(model, data.subset(slice(0, 80)))
    outputs = data.outputs.copy()
    outputs[100, 1] = np.nan
    outputs[120] = np.nan
    gappy = casest.Dataset.from_arrays(model, data.signals, outputs, missing="allow")
    ekf = ParameterEKF(model, theta0, P0, R, iterated=False)
    ekf.run(gappy.subset(slice(80, 100)))
    before_theta, before_P = ekf.theta.copy(), ekf.P.copy()
    assert ekf.update(gappy.signals[100:101], gappy.outputs[100:101]) == 1
    # the same update written out on channels 0 and 2
    h, H = casest.backend.sums.prediction_and_jacobian(model, gappy.signals[100:101], before_theta)
    rows = [0, 2]
    S = H[rows] @ before_P @ H[rows].T + np.diag(R[rows])
    K = before_P @ H[rows].T @ np.linalg.inv(S)
    np.testing.assert_allclose(ekf.theta, before_theta + K @ (gappy.outputs[100, rows] - h[rows]), rtol=1e-9)
    assert ekf.update(gappy.signals[120:121], gappy.outputs[120:121]) == 0
    ekf.run(gappy.subset(slice(121, None)))
    assert np.all(np.isfinite(ekf.theta)) and np.all(np.isfinite(ekf.P))
