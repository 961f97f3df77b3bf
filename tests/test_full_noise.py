"""Unknown full noise covariance (correlated channels), log-Cholesky parametrised.

Truths: at the ML optimum R equals the residual covariance r'r / N (analytic: the cost's
stationarity in R), and theta equals the generalised least squares with that R (SciPy trf on
whitened residuals) to 1e-7; on five seeds of the triad with noise correlation 0.6 the
estimated correlations lie within 0.15 of 0.6 and the parameters within 3 std of the truth.
The 300-run Monte-Carlo check is ``python3 scripts/campaigns/full_noise_mc.py``.
"""

import os

import numpy as np
from scipy.optimize import least_squares

import casest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
hard = casest.load_model_file(os.path.join(REPO, "models", "robustness.py"))
TRUTH = {"sx": 0.03, "sy": -0.05, "sz": 0.02, "bx": 1.0, "by": -2.0, "bz": 0.5, "psi": 2.4}
STD, RHO = np.array([0.5, 1.0, 2.0]), 0.6


def correlated_triad(seed):
    model, data = hard.triad(seed)
    C = (np.full((3, 3), RHO) + (1 - RHO) * np.eye(3)) * np.outer(STD, STD)
    clean = model.predict(model.vector(TRUTH), data.signals)
    noise = np.random.default_rng(500 + seed).standard_normal(clean.shape) @ np.linalg.cholesky(C).T
    return model, casest.Dataset.from_arrays(model, data.signals, clean + noise)


def test_full_noise_is_the_ml_fixed_point():
    model, data = correlated_triad(0)
    est = casest.estimate(model, data, noise=casest.CorrelatedNoise())
    assert est.success and est.R_full is not None
    resid = data.outputs - model.predict(est.theta, data.signals)
    np.testing.assert_allclose(est.R_full, resid.T @ resid / data.n_samples, rtol=1e-8, atol=1e-12)
    W = np.linalg.cholesky(np.linalg.inv(est.R_full))  # whitening: ||W' r||^2 = r' R^-1 r

    def whitened(theta):
        return ((data.outputs - model.predict(theta, data.signals)) @ W).reshape(-1)

    gls = least_squares(whitened, est.theta + 1e-3, bounds=(model.lower_bounds, model.upper_bounds), method="trf",
                        xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    np.testing.assert_allclose(est.theta, gls, rtol=1e-7, atol=1e-9)
    assert "noise correlation(mx, my)" in est.report()


def test_full_noise_recovers_the_correlation():
    inside = 0
    for seed in range(5):
        model, data = correlated_triad(seed)
        est = casest.estimate(model, data, noise=casest.CorrelatedNoise())
        sd = np.sqrt(np.diag(est.R_full))
        corr = (est.R_full / np.outer(sd, sd))[np.triu_indices(3, 1)]
        assert np.all(np.abs(corr - RHO) < 0.15), corr
        inside += np.all(np.abs(est.theta - model.vector(TRUTH)) < 3 * est.std)
    assert inside >= 4
