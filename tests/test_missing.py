"""Missing outputs (NaN with missing="allow"): those residuals leave every sum.

Truths: (1) one output with 30 % of its samples missing equals the same estimate on the
kept rows (scalar example 1, seed 0), to 1e-8; (2) on the three-channel triad with 30 % of
one channel missing, the estimate equals an independent ML fit written by hand with SciPy
(weighted least squares on the measured entries, R_j = RSS_j / N_j iterated to convergence),
to 1e-7, and R_j equals RSS_j / N_j.
"""

import os

import numpy as np
import pytest
from scipy.optimize import least_squares

import casest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
hard = casest.load_model_file(os.path.join(REPO, "models", "robustness.py"))
scalar1 = casest.load_model_file("scalar1")


def test_missing_rows_equal_dropped_rows():
    model, data = scalar1.model(), scalar1.simulate(0)
    drop = np.random.default_rng(1).random(data.n_samples) < 0.3
    z = data.column("z").copy()
    z[drop] = np.nan
    with_gaps = casest.Dataset(model, {"eta": data.column("eta"), "z": z}, missing="allow")
    assert with_gaps.has_missing and with_gaps.observed_counts()[0] == (~drop).sum()
    kept = data.subset(~drop)
    est, ref = casest.estimate(model, with_gaps), casest.estimate(model, kept)
    assert est.success and ref.success
    np.testing.assert_allclose(est.theta, ref.theta, rtol=1e-8)
    np.testing.assert_allclose(est.std, ref.std, rtol=1e-8)
    np.testing.assert_allclose(est.R, ref.R, rtol=1e-8)
    np.testing.assert_allclose(est.cost, ref.cost, rtol=1e-10)
    gn = casest.estimate(model, with_gaps, covariance="gauss-newton")
    np.testing.assert_allclose(gn.std, casest.estimate(model, kept, covariance="gauss-newton").std, rtol=1e-8)


def test_missing_in_one_of_three_channels_equals_a_hand_written_ml_fit():
    model, data = hard.triad(1)
    outputs = data.outputs.copy()
    gone = np.random.default_rng(2).random(data.n_samples) < 0.3
    outputs[gone, 1] = np.nan
    gapped = casest.Dataset.from_arrays(model, data.signals, outputs, missing="allow")
    est = casest.estimate(model, gapped)
    assert est.success
    seen = np.isfinite(outputs)
    N = data.n_samples
    f, jf = model.function.map(N), model.jacobian_function.map(N)
    keep = seen.T.reshape(-1)  # channel-major, as CasADi returns h

    def fit(theta, weights):
        w = np.repeat(weights, N)[keep]
        z = np.nan_to_num(outputs).T.reshape(-1)[keep]
        return least_squares(lambda th: (np.asarray(f(data.signals.T, th)).reshape(-1)[keep] - z) * w, theta,
                             jac=lambda th: np.asarray(jf(data.signals.T, th)[1]).reshape(-1, model.n_parameters)[keep]
                             * w[:, None], bounds=(model.lower_bounds, model.upper_bounds), method="trf",
                             xtol=1e-15, ftol=1e-15, gtol=1e-15).x

    theta, weights = est.theta + 1e-3, np.ones(3)
    for _ in range(100):
        theta = fit(theta, weights)
        resid = np.where(seen, outputs - model.predict(theta, data.signals), 0.0)
        R = np.sum(resid**2, axis=0) / seen.sum(axis=0)
        if np.allclose(1 / np.sqrt(R), weights, rtol=1e-13):
            break
        weights = 1 / np.sqrt(R)
    np.testing.assert_allclose(est.theta, theta, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(est.R, R, rtol=1e-7)


def test_missing_stays_an_error_by_default():
    model, data = scalar1.model(), scalar1.simulate(0)
    z = data.column("z").copy()
    z[[3, 7]] = np.nan
    with pytest.raises(casest.DataError, match=r"row\(s\) 3, 7 .*missing='allow'"):
        casest.Dataset(model, {"eta": data.column("eta"), "z": z})
    eta = data.column("eta").copy()
    eta[2] = np.nan
    with pytest.raises(casest.DataError, match="'eta' has 1 NaN"):
        casest.Dataset(model, {"eta": eta, "z": data.column("z")}, missing="allow")  # signals: always an error
