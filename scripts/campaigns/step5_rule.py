#!/usr/bin/env python3
"""The paper's Step 5 rule (``mode="paper"``) against casest's ``mode="auto"`` on the paper's examples.

    python3 scripts/campaigns/step5_rule.py [--runs 100]

For each of paper scalar examples 1 and 2, ``--runs`` simulated records (seeds 0, 1, ...), each
estimated in both modes: the total time per mode, how often each ends above the better of the two
ML costs (by more than 1e-6), and which stage-2 modes each ran. The robustness suite gives the
same comparison on 44 harder problems: ``python3 scripts/campaigns/robustness.py --mode paper``
against ``--mode auto``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402

MODES = ("auto", "paper")


def compare(name: str, runs: int) -> str:
    """One line: the example's times, runs above the better cost, and the modes that ran."""
    module = casest.load_model_file(name)
    model = module.model()
    seconds, worse, ran = dict.fromkeys(MODES, 0.0), dict.fromkeys(MODES, 0), {m: {} for m in MODES}
    for seed in range(runs):
        problem = casest.Problem(model, module.simulate(seed=seed))
        cost = {}
        for mode in MODES:
            t = time.perf_counter()
            est = casest.estimate(problem, mode=mode)
            seconds[mode] += time.perf_counter() - t
            cost[mode] = problem.profile_cost(est.theta)
            ran[mode][est.mode] = ran[mode].get(est.mode, 0) + 1
        best = min(cost.values())
        for mode in MODES:
            worse[mode] += cost[mode] > best + 1e-6
    return (f"{name}: {runs} runs; seconds " + ", ".join(f"{m} {seconds[m]:.2f}" for m in MODES)
            + "; above the better cost " + ", ".join(f"{m} {worse[m]}" for m in MODES)
            + "; stage-2 modes " + "; ".join(f"{m}: {ran[m]}" for m in MODES))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=100)
    args = parser.parse_args(argv)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name in ("scalar1", "scalar2"):
            print(compare(name, args.runs), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
