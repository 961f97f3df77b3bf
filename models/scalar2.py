"""Scalar example 2 of the paper (Sec. III, Eq. 33-34).

    z_k = (1 + a) cos(eta_k (1 + b) + c) + d + v_k,    v_k ~ N(0, 0.3**2)

Truth a = 1, b = 0.05, c = 0.1, d = 1; N = 100 samples with eta evenly spaced on
[1, 10] rad. The separator finds xi1 = [a, d] and xi2 = [b, c] (Eq. 34); stage 1 sweeps
b on [0, 0.5] and c on [0, 1].

Run ``python models/scalar2.py`` to simulate one data set and estimate it.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

import casest

TRUTH = {"a": 1.0, "b": 0.05, "c": 0.1, "d": 1.0}
NOISE_STD = 0.3

#: Benchmark 1's random starts (paper Sec. III.C): a, d ~ N(0, 1), b, c ~ N(0, 0.1^2).
BENCHMARK1_STARTS = {
    "a": casest.Gaussian(0.0, 1.0),
    "b": casest.Gaussian(0.0, 0.1),
    "c": casest.Gaussian(0.0, 0.1),
    "d": casest.Gaussian(0.0, 1.0),
}


def model() -> casest.Model:
    """The measurement model of Eq. 33 with the paper's ranges for b and c."""
    a, b, c, d, eta = (ca.SX.sym(n) for n in ("a", "b", "c", "d", "eta"))
    return casest.Model(
        parameters=[
            casest.Parameter("a", nominal=0.0, prior=casest.Gaussian(0.0, 1.0)),
            casest.Parameter("b", lb=0.0, ub=0.5, nominal=0.0),
            casest.Parameter("c", lb=0.0, ub=1.0, nominal=0.0, unit="rad"),
            casest.Parameter("d", nominal=0.0, prior=casest.Gaussian(0.0, 1.0)),
        ],
        signals=[casest.Signal("eta", unit="rad")],
        outputs={"z": (1 + a) * ca.cos(eta * (1 + b) + c) + d},
        name="scalar2",
    )


def simulate(seed: int = 0, n: int = 100, noise_std: float = NOISE_STD, truth=None) -> casest.Dataset:
    """Data of the paper's setting: eta evenly spaced on [1, 10], Gaussian noise.

    Parameters
    ----------
    seed : int
        Seed of the noise draw.
    n : int
        Number of samples N.
    noise_std : float
        Standard deviation of v_k (0 gives noiseless data).
    truth : mapping, optional
        Parameter values; default :data:`TRUTH`.
    """
    m = model()
    eta = np.linspace(1.0, 10.0, n)
    z = m.predict(truth or TRUTH, eta[:, None])[:, 0]
    z = z + noise_std * np.random.default_rng(seed).standard_normal(n)
    return casest.Dataset(m, {"eta": eta, "z": z})


def main(seed: int = 0) -> casest.Estimate:
    """Simulate with ``seed``, estimate, print the report and return the Estimate."""
    result = casest.estimate(model(), simulate(seed))
    print(result.report())
    return result


if __name__ == "__main__":
    main()
