"""Gaussian priors as penalties (MAP) on a linear model equal the closed-form posterior.

Truth: y = a + b x + c x^2 with known noise std 0.3, priors a ~ N(1, 0.5^2), b ~ N(0, 0.2^2)
and none on c; the posterior precision is A'A / s^2 + diag(1/0.5^2, 1/0.2^2, 0), its mean
P^-1 (A'z / s^2 + prior precision x prior mean). Agreement to 1e-8.
"""

import casadi as ca
import numpy as np

import casest


def test_map_equals_the_closed_form_posterior():
    a, b, c, x = (ca.SX.sym(n) for n in ("a", "b", "c", "x"))
    model = casest.Model(
        [casest.Parameter("a", prior=casest.Gaussian(1.0, 0.5)), casest.Parameter("b", prior=casest.Gaussian(0.0, 0.2)),
         casest.Parameter("c", nominal=0.0)],
        ["x"], {"y": a + b * x + c * x**2}, name="quadratic")
    rng = np.random.default_rng(7)
    xs = np.linspace(-1.0, 1.0, 12)
    y = 0.4 + 0.9 * xs - 0.5 * xs**2 + 0.3 * rng.standard_normal(xs.size)
    data = casest.Dataset(model, {"x": xs, "y": y})
    est = casest.estimate(model, data, noise=casest.KnownNoise({"y": 0.3}), prior_penalty=True)
    A = np.column_stack([np.ones_like(xs), xs, xs**2])
    precision = np.array([1 / 0.5**2, 1 / 0.2**2, 0.0])
    P = A.T @ A / 0.09 + np.diag(precision)
    mean = np.linalg.solve(P, A.T @ y / 0.09 + precision * np.array([1.0, 0.0, 0.0]))
    assert est.success
    np.testing.assert_allclose(est.theta, mean, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(est.covariance, np.linalg.inv(P), rtol=1e-8, atol=1e-14)
    # without the penalty the estimate is the plain weighted least squares
    plain = casest.estimate(model, data, noise=casest.KnownNoise({"y": 0.3}))
    np.testing.assert_allclose(plain.theta, np.linalg.lstsq(A, y, rcond=None)[0], rtol=1e-8)
