"""Scalar example 1 of the paper (Sec. III, Eq. 21-22).

    z_k = (1 + a) cos(eta_k + b) + c + v_k,    v_k ~ N(0, 0.3**2)

Truth a = 1, b = 0.1, c = 1; N = 100 samples with eta evenly spaced on [1, 10] rad.
The separator finds xi1 = [a, c] and xi2 = [b] (Eq. 22); stage 1 sweeps b on [0, 0.2].

Run ``python models/scalar1.py`` to simulate one data set and estimate it.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

import casest

TRUTH = {"a": 1.0, "b": 0.1, "c": 1.0}
NOISE_STD = 0.3

#: Benchmark 1's random starts (paper Sec. III.C): a, c ~ N(0, 1), b ~ N(0, 0.1^2).
BENCHMARK1_STARTS = {"a": casest.Gaussian(0.0, 1.0), "b": casest.Gaussian(0.0, 0.1), "c": casest.Gaussian(0.0, 1.0)}


def model() -> casest.Model:
    """The measurement model of Eq. 21 with the paper's prior range for b."""
    a, b, c, eta = (ca.SX.sym(n) for n in ("a", "b", "c", "eta"))
    return casest.Model(
        parameters=[
            casest.Parameter("a", nominal=0.0, prior=casest.Gaussian(0.0, 1.0)),
            casest.Parameter("b", lb=0.0, ub=0.2, nominal=0.0, unit="rad"),
            casest.Parameter("c", nominal=0.0, prior=casest.Gaussian(0.0, 1.0)),
        ],
        signals=[casest.Signal("eta", unit="rad")],
        outputs={"z": (1 + a) * ca.cos(eta + b) + c},
        name="scalar1",
    )


def change_of_variables() -> "casest.apps.baselines.ChangeOfVariables":
    """Paper Eq. 28: z = H(eta) y with y = [a cos b, a sin b, cos b, sin b, c].

    Columns 1-2 of H equal columns 3-4, so H is rank-deficient (the paper's pitfall of
    Benchmark 2); the first step takes the minimum-norm solution.
    """
    from casest.apps.baselines import ChangeOfVariables

    eta = ca.SX.sym("eta")
    a, b, c = ca.SX.sym("a"), ca.SX.sym("b"), ca.SX.sym("c")
    H = ca.horzcat(ca.cos(eta), -ca.sin(eta), ca.cos(eta), -ca.sin(eta), 1)
    y = ca.vertcat(a * ca.cos(b), a * ca.sin(b), ca.cos(b), ca.sin(b), c)
    return ChangeOfVariables(
        H=ca.Function("H", [eta], [H]),
        f=ca.Function("f", [ca.vertcat(a, b, c)], [y]),
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
