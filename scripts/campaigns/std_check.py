#!/usr/bin/env python3
"""Reported standard deviations against the Monte-Carlo spread of the estimates.

    python3 scripts/campaigns/std_check.py MODEL [--runs 200] [--first-seed 0] [--covariance hessian]

Runs casest.estimate on MODEL's simulate(seed) for consecutive seeds and prints, per
parameter, the mean reported std, the sample std of the estimates, their ratio and the
coverage of the +/-2 std intervals.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402
from casest.apps.montecarlo import std_against_spread  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model")
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--covariance", default="hessian", choices=list(casest.estimation.uncertainty.COVARIANCE_METHODS))
    args = parser.parse_args(argv)
    module = casest.load_model_file(args.model)
    t0 = time.perf_counter()
    check = std_against_spread(module, args.runs, args.first_seed, covariance=args.covariance)
    print(f"{args.model}: {args.runs} runs (seeds {args.first_seed}..{args.first_seed + args.runs - 1}), "
          f"{check.n_failed} failed, {time.perf_counter() - t0:.1f} s, covariance {args.covariance}")
    print(check.table())
    return 0


if __name__ == "__main__":
    sys.exit(main())
