#!/usr/bin/env python3
"""Monte-Carlo check of the unknown full noise covariance (casest.CorrelatedNoise).

    python3 scripts/campaigns/full_noise_mc.py [--runs 300] [--first-seed 0]

Three-channel triad calibration (models/robustness.py) with noise std 0.5, 1, 2 and every
pair correlated 0.6; each run draws new noise and estimates theta and the full R. Prints
the mean estimated correlation per pair with its Monte-Carlo standard error (unbiased when
the mean is within about 2 standard errors of 0.6, up to the ML bias of order 1/N), the
+/-2 sigma coverage of every parameter (target 95 +/- 2.5 %), and the ratio of the
Monte-Carlo spread to the mean reported std.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import numpy as np  # noqa: E402

import casest  # noqa: E402

REPO = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
TRUTH = {"sx": 0.03, "sy": -0.05, "sz": 0.02, "bx": 1.0, "by": -2.0, "bz": 0.5, "psi": 2.4}
STD, RHO = np.array([0.5, 1.0, 2.0]), 0.6


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=300)
    parser.add_argument("--first-seed", type=int, default=0)
    args = parser.parse_args(argv)
    hard = casest.load_model_file(os.path.join(REPO, "models", "robustness.py"))
    C = (np.full((3, 3), RHO) + (1 - RHO) * np.eye(3)) * np.outer(STD, STD)
    Lc = np.linalg.cholesky(C)
    thetas, stds, corrs, failed = [], [], [], 0
    t0 = time.perf_counter()
    for run in range(args.runs):
        seed = args.first_seed + run
        model, data = hard.triad(seed)
        truth = model.vector(TRUTH)
        clean = model.predict(truth, data.signals)
        noisy = clean + np.random.default_rng(10_000 + seed).standard_normal(clean.shape) @ Lc.T
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est = casest.estimate(model, casest.Dataset.from_arrays(model, data.signals, noisy),
                                  noise=casest.CorrelatedNoise())
        if not est.success:
            failed += 1
            continue
        sd = np.sqrt(np.diag(est.R_full))
        corrs.append((est.R_full / np.outer(sd, sd))[np.triu_indices(3, 1)])
        thetas.append(est.theta)
        stds.append(est.std)
    thetas, stds, corrs = np.array(thetas), np.array(stds), np.array(corrs)
    truth = model.vector(TRUTH)
    print(f"{len(thetas)} of {args.runs} runs converged ({failed} failed); {time.perf_counter() - t0:.1f} s")
    for k, pair in enumerate(("mx-my", "mx-mz", "my-mz")):
        mean, se = corrs[:, k].mean(), corrs[:, k].std(ddof=1) / np.sqrt(len(corrs))
        print(f"correlation {pair}: mean {mean:.4f} +/- {se:.4f} (truth {RHO}; {abs(mean - RHO) / se:.1f} standard errors)")
    covered = np.abs(thetas - truth) <= 2 * stds
    for i, name in enumerate(model.parameter_names):
        print(f"{name:>4}: +/-2 sigma coverage {100 * covered[:, i].mean():.1f} %, MC std / mean reported std "
              f"{thetas[:, i].std(ddof=1):.4g} / {stds[:, i].mean():.4g} = {thetas[:, i].std(ddof=1) / stds[:, i].mean():.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
