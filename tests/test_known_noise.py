"""Known noise (R given): the estimate is the weighted least squares, the std come from the given R.

Independent truths: SciPy ``least_squares`` (trf, exact Jacobian) on the residuals divided by
the given std, to 1e-8; the Gauss-Newton covariance (J' R^-1 J)^-1 at SciPy's solution; the
exact-Hessian std against a central-difference Hessian of 1/2 sum r^2 / R.
"""

import os

import numpy as np
import pytest
from scipy.optimize import least_squares

import casest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
hard = casest.load_model_file(os.path.join(REPO, "models", "robustness.py"))
scalar2 = casest.load_model_file("scalar2")


def _weighted_ls(model, data, std, theta0):
    N = data.n_samples
    f, jf = model.function.map(N), model.jacobian_function.map(N)
    w = np.repeat(1.0 / np.asarray(std), N)  # channel-major, as CasADi returns h
    z = data.outputs.T.reshape(-1)
    res = least_squares(lambda th: (np.asarray(f(data.signals.T, th)).reshape(-1) - z) * w, theta0,
                        jac=lambda th: np.asarray(jf(data.signals.T, th)[1]).reshape(-1, model.n_parameters) * w[:, None],
                        bounds=(model.lower_bounds, model.upper_bounds), method="trf", xtol=1e-15, ftol=1e-15,
                        gtol=1e-15)
    return res.x, res.jac


@pytest.mark.parametrize("case", ["scalar2", "triad"])
def test_known_noise_is_weighted_least_squares(case):
    if case == "scalar2":
        model, data, std = scalar2.model(), scalar2.simulate(0), [0.3]
    else:
        (model, data), std = hard.triad(1), [0.5, 1.0, 2.0]
    noise = casest.KnownNoise(dict(zip(model.output_names, std)))
    est = casest.estimate(model, data, noise=noise, covariance="gauss-newton")
    assert est.success
    np.testing.assert_allclose(est.R, np.square(std), rtol=0, atol=0)  # held exactly
    theta, J = _weighted_ls(model, data, std, np.clip(est.theta + 1e-3 * model.scales, model.lower_bounds,
                                                       model.upper_bounds))
    np.testing.assert_allclose(est.theta, theta, rtol=1e-8, atol=1e-10)
    reference_std = np.sqrt(np.diag(np.linalg.inv(J.T @ J)))  # J already divided by the std
    np.testing.assert_allclose(est.std, reference_std, rtol=1e-6)
    assert "known noise variance" in est.report() and est.noise_model.startswith("known R")


def test_known_noise_hessian_std():
    """Default covariance: inverse exact Hessian of 1/2 sum r^2/R in theta, against central differences."""
    model, data = scalar2.model(), scalar2.simulate(3)
    R = 0.3**2
    est = casest.estimate(model, data, noise=casest.KnownNoise({"z": 0.3}))

    def cost(th):
        return 0.5 * np.sum((data.outputs[:, 0] - model.predict(th, data.signals)[:, 0]) ** 2) / R

    n, h = model.n_parameters, 1e-4 * model.scales
    H = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            e_i, e_j = np.eye(n)[i] * h[i], np.eye(n)[j] * h[j]
            H[i, j] = (cost(est.theta + e_i + e_j) - cost(est.theta + e_i - e_j) - cost(est.theta - e_i + e_j)
                       + cost(est.theta - e_i - e_j)) / (4 * h[i] * h[j])
    np.testing.assert_allclose(est.std, np.sqrt(np.diag(np.linalg.inv(H))), rtol=1e-5)


def test_known_noise_errors():
    model = scalar2.model()
    with pytest.raises(casest.ModelError, match=r"missing: \['z'\]"):
        casest.KnownNoise({"y": 1.0}).variances(model)
    with pytest.raises(casest.ModelError, match="positive finite"):
        casest.KnownNoise({"z": 0.0}).variances(model)
