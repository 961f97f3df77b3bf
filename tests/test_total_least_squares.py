"""Total least squares (casest.total_least_squares): equation error with noisy regressors.

Truths: the closed form of Golub and Van Loan, theta = (X'X - s^2 I)^-1 X'y with s the smallest
singular value of [X y] (no exact columns); the analytic truth of simulated errors-in-variables
records (fixed seeds), where ordinary least squares is biased towards zero and total least
squares is not, and the reported std match the Monte-Carlo spread.
"""

import casadi as ca
import numpy as np
import pytest

import casest

X1, X2 = ca.SX.sym("x1"), ca.SX.sym("x2")
TERMS = {"bias": 1, "x1": X1, "x2": X2}
TRUTH = np.array([2.0, 1.5, -0.8])
NOISE = {"y": 0.2, "x1": 0.4, "x2": 0.4}


def errors_in_variables(seed, N=400):
    """y = 2 + 1.5 x1 - 0.8 x2 + noise (std 0.2); x1 and x2 correlated, measured with std 0.4."""
    rng = np.random.default_rng(seed)
    t1 = rng.normal(0, 1, N)
    t2 = 0.5 * t1 + rng.normal(0, 1, N)
    y = TRUTH[0] + TRUTH[1] * t1 + TRUTH[2] * t2 + NOISE["y"] * rng.standard_normal(N)
    return y, {"x1": t1 + NOISE["x1"] * rng.standard_normal(N), "x2": t2 + NOISE["x2"] * rng.standard_normal(N)}


def test_the_closed_form_of_golub_and_van_loan():
    y, data = errors_in_variables(0)
    terms = {"x1": X1, "x2": X2}
    fit = casest.total_least_squares(y, terms, data)
    X = np.column_stack([data["x1"], data["x2"]])
    s = np.linalg.svd(np.column_stack([X, y]), compute_uv=False)[-1]
    closed = np.linalg.solve(X.T @ X - s**2 * np.eye(2), X.T @ y)
    np.testing.assert_allclose(fit.theta, closed, rtol=1e-10)
    assert fit.method == "total least squares" and "total least squares" in fit.table()


def test_exact_data_give_the_truth():
    rng = np.random.default_rng(3)
    data = {"x1": rng.normal(size=50), "x2": rng.normal(size=50)}
    y = TRUTH[0] + TRUTH[1] * data["x1"] + TRUTH[2] * data["x2"] + 1e-9 * rng.normal(size=50)
    np.testing.assert_allclose(casest.total_least_squares(y, TERMS, data).theta, TRUTH, rtol=1e-7)


def test_monte_carlo_unbiased_with_std_matching_the_spread():
    """200 records: the mean within 3 standard errors of the truth (least squares misses the x1
    slope by more than 10), the spread within 15 % of the mean reported std, and 95 % of the
    estimates within 1.96 std (binomial 3-sigma band 92.9-97.1 % over 600)."""
    tls, ols, std = [], [], []
    for seed in range(200):
        y, data = errors_in_variables(seed)
        fit = casest.total_least_squares(y, TERMS, data, noise_std=NOISE)
        tls.append(fit.theta)
        std.append(fit.std)
        ols.append(casest.regress(y, TERMS, data, colored=False).theta)
    tls, ols, std = np.array(tls), np.array(ols), np.array(std)
    standard_error = tls.std(axis=0) / np.sqrt(len(tls))
    assert np.all(np.abs(tls.mean(axis=0) - TRUTH) < 3 * standard_error), tls.mean(axis=0)
    assert abs(ols.mean(axis=0)[1] - TRUTH[1]) > 10 * ols.std(axis=0)[1] / np.sqrt(len(ols))
    np.testing.assert_allclose(tls.std(axis=0) / std.mean(axis=0), 1.0, atol=0.15)
    inside = np.mean(np.abs(tls - TRUTH) / std < 1.96)
    assert 0.929 < inside < 0.971, inside


def test_the_mistakes_are_named():
    y, data = errors_in_variables(1, N=50)
    with pytest.raises(casest.OptionError, match="exact names"):
        casest.total_least_squares(y, TERMS, data, exact=["x3"])
    with pytest.raises(casest.OptionError, match="noise_std names"):
        casest.total_least_squares(y, TERMS, data, noise_std={"alpha": 1.0})
    with pytest.raises(casest.OptionError, match="positive"):
        casest.total_least_squares(y, TERMS, data, noise_std={"x1": 0.0})
    with pytest.raises(casest.DataError, match="linear combinations"):
        casest.total_least_squares(y, {**TERMS, "twice": 2 * X1}, data)
