"""Monte-Carlo checks of the estimator on simulated data with known truth."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from .pipeline import estimate

__all__ = ["SpreadCheck", "std_against_spread"]


@dataclass
class SpreadCheck:
    """Reported standard deviations against the Monte-Carlo spread of the estimates.

    Attributes
    ----------
    names : tuple of str
    estimates : ndarray, shape (runs, n_parameters)
    reported_std : ndarray, shape (runs, n_parameters)
        NaN where a run reported none (parameter on a bound).
    truth : ndarray, shape (n_parameters,)
    ratio : ndarray, shape (n_parameters,)
        Mean reported std / sample std of the estimates.
    coverage : ndarray, shape (n_parameters,)
        Fraction of runs with |estimate - truth| <= 2 reported std (runs with a std).
    n_failed : int
        Runs whose stage 2 did not converge (excluded).
    """

    names: tuple
    estimates: np.ndarray
    reported_std: np.ndarray
    truth: np.ndarray
    ratio: np.ndarray
    coverage: np.ndarray
    n_failed: int

    def table(self) -> str:
        lines = [f"{'param':>8} {'truth':>10} {'mean est':>10} {'MC std':>10} {'mean std':>10} {'ratio':>7} {'2-sigma cov':>11}"]
        mc = np.std(self.estimates, axis=0, ddof=1)
        rep = np.nanmean(self.reported_std, axis=0)
        for i, n in enumerate(self.names):
            lines.append(
                f"{n:>8} {self.truth[i]:>10.5g} {np.mean(self.estimates[:, i]):>10.5g} {mc[i]:>10.4g} "
                f"{rep[i]:>10.4g} {self.ratio[i]:>7.3f} {100 * self.coverage[i]:>10.1f}%"
            )
        return "\n".join(lines)


def std_against_spread(module, runs: int = 200, first_seed: int = 0, **estimate_kw) -> SpreadCheck:
    """Estimate ``runs`` data sets from ``module.simulate(seed)`` and compare std with spread.

    Parameters
    ----------
    module : model-file module
        Needs ``model()``, ``simulate(seed)`` and ``TRUTH``.
    runs : int
    first_seed : int
        Seeds ``first_seed .. first_seed + runs - 1``.
    **estimate_kw
        Passed to :func:`casest.estimate`.
    """
    model = module.model()
    truth = model.vector(module.TRUTH)
    est, std = [], []
    failed = 0
    for seed in range(first_seed, first_seed + runs):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            result = estimate(model, module.simulate(seed), **estimate_kw)
        if not result.success:
            failed += 1
            continue
        est.append(result.theta)
        std.append(result.std)
    est, std = np.array(est), np.array(std)
    mc = np.std(est, axis=0, ddof=1)
    ratio = np.nanmean(std, axis=0) / mc
    with np.errstate(invalid="ignore"):
        inside = np.abs(est - truth) <= 2 * std
    coverage = np.array([inside[np.isfinite(std[:, i]), i].mean() for i in range(len(truth))])
    return SpreadCheck(model.parameter_names, est, std, truth, ratio, coverage, failed)
