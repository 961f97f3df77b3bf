#!/usr/bin/env python3
"""Online magnetometer calibration: a two-stage batch estimate on a first window, then the
iterated EKF over the rest of the record (paper end of Sec. II).

    python3 scripts/examples/online_calibration.py [--seed N] [--samples 2000] [--window 100] [--out DIR]
    python3 scripts/examples/online_calibration.py --compare 50 [--samples 600] [--window 60]

The first form writes DIR/online_parameters.png (each parameter and its +/-2 sigma band
over the samples, against the truth) and prints the filter's final estimate beside the
batch estimate on all the data. ``--compare K`` runs K seeded records and reports, for
the iterated EKF seeded by stage 1 on the window and for the same filter started from the
zero initial guess (P0 = diag(scale^2)), how often every parameter ends within 3 sigma of
the truth.
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
from casest.recursive.least_squares import ParameterEKF  # noqa: E402
from casest.two_stage import seed_from_stage1  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def one_record(module, seed: int, samples: int, window: int, out: str | None):
    model = module.model()
    data = module.simulate(seed, n=samples)
    first, rest = data.subset(slice(0, window)), data.subset(slice(window, None))
    seed_est = casest.estimate(model, first)
    ekf = ParameterEKF.from_estimate(model, seed_est)
    t = time.perf_counter()
    hist = ekf.run(rest, record_every=10)
    t_filter = time.perf_counter() - t
    batch = casest.estimate(model, data)
    truth = model.vector(module.TRUTH)
    print(f"seed {seed}: batch on the first {window} samples, then the iterated EKF over {rest.n_samples} "
          f"({t_filter:.2f} s, mean {hist.iterations.mean():.2f} iterations per sample)")
    print(f"{'parameter':>10} {'truth':>9} {'EKF':>10} {'EKF std':>9} {'batch':>10} {'batch std':>9} {'std ratio':>9}")
    for i, name in enumerate(model.parameter_names):
        print(f"{name:>10} {truth[i]:>9.4f} {ekf.theta[i]:>10.5f} {ekf.std[i]:>9.2e} {batch.theta[i]:>10.5f} "
              f"{batch.std[i]:>9.2e} {ekf.std[i] / batch.std[i]:>9.3f}")
    z = (ekf.theta - truth) / ekf.std
    print(f"EKF: max |estimate - truth| / std = {np.max(np.abs(z)):.2f}")
    if out:
        from casest.apps.plots import pyplot_module, save_png

        plt = pyplot_module()
        n = model.n_parameters
        fig, axes = plt.subplots(4, 3, figsize=(12, 9), sharex=True)
        x = window + hist.index
        for i, ax in enumerate(axes.ravel()[:n]):
            ax.fill_between(x, hist.theta[:, i] - 2 * hist.std[:, i], hist.theta[:, i] + 2 * hist.std[:, i],
                            color="C0", alpha=0.25, lw=0, label="±2σ")
            ax.plot(x, hist.theta[:, i], "C0", lw=1, label="iterated EKF")
            ax.axhline(truth[i], color="k", ls="--", lw=0.8, label="truth")
            ax.axhline(batch.theta[i], color="C3", ls=":", lw=1, label="batch, all data")
            ax.set_title(model.parameter_names[i], fontsize=9)
            lo, hi = truth[i] - 6 * batch.std[i] * np.sqrt(samples / window), truth[i] + 6 * batch.std[i] * np.sqrt(samples / window)
            ax.set_ylim(lo, hi)
        axes[0, 0].legend(fontsize=7)
        for ax in axes[-1]:
            ax.set_xlabel("samples processed")
        fig.tight_layout()
        path = save_png(fig, os.path.join(out, "online_parameters.png"))
        plt.close(fig)
        print("wrote", path)
    return ekf, batch


def compare(module, runs: int, samples: int, window: int) -> None:
    model = module.model()
    truth = model.vector(module.TRUTH)
    inside = {"stage-1 seed": 0, "zero initial guess": 0}
    t = time.perf_counter()
    for seed in range(runs):
        data = module.simulate(1000 + seed, n=samples)
        first = data.subset(slice(0, window))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            R = casest.estimate(model, first).R  # the same measurement noise for both filters
        theta0, P0, _, _ = seed_from_stage1(model, first)
        starts = {"stage-1 seed": (theta0, P0, data.subset(slice(window, None))),
                  "zero initial guess": (np.zeros(model.n_parameters), np.diag(model.scales**2), data)}
        for label, (th0, P, record) in starts.items():
            ekf = ParameterEKF(model, th0, P, R)
            ekf.run(record)
            inside[label] += bool(np.all(np.abs(ekf.theta - truth) < 3 * ekf.std))
    print(f"{runs} records of {samples} samples (seeds 1000-{999 + runs}), window {window}, {time.perf_counter() - t:.1f} s:")
    for label, count in inside.items():
        print(f"  iterated EKF from the {label}: every parameter within 3 sigma of the truth in {count}/{runs} "
              f"({100 * count / runs:.0f}%)")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--samples", type=int, default=None)
    parser.add_argument("--window", type=int, default=None)
    parser.add_argument("--out", default="out/online")
    parser.add_argument("--compare", type=int, default=0, metavar="K")
    args = parser.parse_args(argv)
    module = casest.load_model_file(os.path.join(HERE, "..", "..", "models", "magnetometer.py"))
    if args.compare:
        compare(module, args.compare, args.samples or 600, args.window or 60)
    else:
        one_record(module, args.seed, args.samples or 2000, args.window or 100, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
