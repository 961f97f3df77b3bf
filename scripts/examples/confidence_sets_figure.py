#!/usr/bin/env python3
"""Likelihood-ratio sets from the stage-1 sweep, drawn: a disjoint set and a two-parameter set.

    python3 scripts/examples/confidence_sets_figure.py [--out confidence_sets.png]   # the docs': --out docs/figures/confidence_sets.png

Left: an aliased tone, ``z = a sin(w k) + c`` sampled at integer k (w and 2 pi - w give the same
samples with -a): the sweep's profile deviance of w against the 95 % threshold, and the two
intervals of the set, refined to 1e-9. Right: paper scalar example 2 (seed 0): the sweep's
candidates inside the joint 95 % set of (b, c) (deviance below chi2(0.95, 2)), the profile
intervals of b and c (refined), and the estimate.
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402

import casest  # noqa: E402
from casest.two_stage import confidence_sets  # noqa: E402


def aliased_tone(seed: int = 0):
    """The tone's model and 60 samples (w = 1.1, a = 1.5, c = 0.2, noise 0.3)."""
    w, a, c = (ca.SX.sym(n) for n in ("w", "a", "c"))
    k = ca.SX.sym("k")
    P = casest.Parameter
    model = casest.Model([P("w", 0.3, 2 * np.pi - 0.3, 1.0), P("a"), P("c")], ["k"], {"z": a * ca.sin(w * k) + c})
    kk = np.arange(60.0)
    rng = np.random.default_rng(seed)
    return model, casest.Dataset(model, {"k": kk, "z": 1.5 * np.sin(1.1 * kk) + 0.2 + 0.3 * rng.standard_normal(60)})


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="confidence_sets.png",
                        help="the figure's path (default in the working directory; the docs': docs/figures/confidence_sets.png)")
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    model, data = aliased_tone()
    landscape = casest.sweep(model, data, settings=casest.SweepSettings(n_candidates=4000))
    sets = confidence_sets(model, data, 0.95, landscape=landscape, tol=1e-9)
    order = np.argsort(landscape.candidates[:, 0])
    left.semilogy(landscape.candidates[order, 0], np.maximum(sets.deviance[order], 1e-3), lw=0.8,
                  label="profile deviance (sweep)")
    left.axhline(sets.threshold_single, color="k", ls="--", label="95 % threshold, chi2(1)")
    for a, b in sets.parameters["w"].intervals:
        left.axvspan(a, b, color="tab:orange", alpha=0.35)
    # the two intervals up close: the deviance on a fine grid of explicit candidates around each
    from casest.two_stage.sweep.analysis import profile_cost

    for (a, b), where in zip(sets.parameters["w"].intervals, ([0.12, 0.45, 0.3, 0.35], [0.6, 0.45, 0.3, 0.35])):
        w_fine = np.linspace(a - (b - a), b + (b - a), 201)
        fine = casest.sweep(model, data, candidates=w_fine[:, None])
        D = 2 * (profile_cost(fine.R, data.observed_counts()) - sets.J_min)
        inset = left.inset_axes(where)
        inset.plot(w_fine, D, lw=1)
        inset.axhline(sets.threshold_single, color="k", ls="--", lw=0.8)
        inset.axvspan(a, b, color="tab:orange", alpha=0.35)
        inset.tick_params(labelsize=6)
        inset.set_ylim(0, 3 * sets.threshold_single)
    left.set_xlabel("w (rad per sample)")
    left.set_ylabel("2 (J(w) - J_min)")
    parts = " U ".join(f"[{a:.4f}, {b:.4f}]" for a, b in sets.parameters["w"].intervals)
    left.set_title(f"aliased tone: the 95 % set of w is {len(sets.parameters['w'].intervals)} intervals\n{parts}",
                   fontsize=9)
    left.legend(fontsize=8, loc="lower right")

    m = casest.load_model_file("scalar2")
    model2, data2 = m.model(), m.simulate(seed=0)
    landscape2 = casest.sweep(model2, data2)
    sets2 = confidence_sets(model2, data2, 0.95, landscape=landscape2, tol=1e-9)
    est = casest.estimate(model2, data2)
    inside = sets2.inside
    right.scatter(landscape2.candidates[~inside, 0], landscape2.candidates[~inside, 1], s=3, color="0.8",
                  label="candidates outside")
    right.scatter(landscape2.candidates[inside, 0], landscape2.candidates[inside, 1], s=8, color="tab:blue",
                  label="inside the joint 95 % set")
    (b0, b1), (c0, c1) = sets2.parameters["b"].intervals[0], sets2.parameters["c"].intervals[0]
    right.add_patch(plt.Rectangle((b0, c0), b1 - b0, c1 - c0, fill=False, ec="tab:orange", lw=1.5,
                                  label="profile intervals of b and c"))
    right.plot(est.theta[1], est.theta[2], "k+", markersize=12, label="estimate")
    right.set_xlim(0, 0.12)
    right.set_ylim(0, 0.45)
    right.set_xlabel("b")
    right.set_ylabel("c")
    right.set_title("scalar example 2: the sweep's set of (b, c)", fontsize=9)
    right.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
