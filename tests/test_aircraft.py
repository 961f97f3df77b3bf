"""The aircraft two-step method (summary Sec. 6.3) on a simulated 6-DOF flight.

Truths: the simulator's states, IMU biases, wind and the 32 coefficients it flew with
(fixed seed). Step 1 must be consistent (the NEES of the smoothed 18 states inside its
chi-square(18) 95 % band at >= 90 % of the samples; measured 96-100 % on seeds 0-2) and recover
biases and wind within 3 std; step 2 every coefficient within 3 of the std
that allow for correlated residuals (the smoothed moment equations make them correlated).
"""

import os

import numpy as np
from scipy import stats

import casest
from casest.apps.sim import aircraft as ac

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_two_step_method_recovers_states_and_coefficients():
    mf = casest.load_model_file(os.path.join(REPO, "models", "aircraft.py"))
    record = ac.simulate(1)
    _, filtered, smoothed = mf.reconstruct(record)
    n = record.time.size
    truth = np.hstack([record.states[:, [0, 1, 2, 6, 7, 8, 9, 10, 11]], np.tile(record.imu_bias, (n, 1)),
                       np.tile(record.wind, (n, 1))])
    lo, hi = stats.chi2.ppf([0.025, 0.975], 18)
    nees = smoothed.nees(truth)
    assert np.mean((nees > lo) & (nees < hi)) >= 0.9
    augmented = slice(9, 18)
    assert np.all(np.abs(smoothed.x[0, augmented] - truth[0, augmented]) < 3 * smoothed.std[0, augmented])
    data = mf.regression_data(record, smoothed)
    est = casest.estimate(mf.model(), data)
    assert est.success and est.landscape.verdict == "linear"
    coefficients = mf.model().vector(mf.TRUTH)
    std = mf.colored_residual_std(est, data)
    assert np.all(np.abs(est.theta - coefficients) < 3 * std), (est.theta - coefficients) / std
