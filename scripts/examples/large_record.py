#!/usr/bin/env python3
"""An estimate on a long record, reporting its stages as it goes (time so far, peak memory).

    python3 scripts/examples/large_record.py [--samples 10000000] [--seed 0]

Paper scalar example 2 (``models/scalar2.py``) simulated with the given number of samples and
estimated with ``progress=True``: each stage (separation, stage 1 with its candidates, stage 2
with its starts, the covariance) prints a line on standard error as it starts, and the report
follows.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000_000, help="samples of the record (default 1e7)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    module = casest.load_model_file("scalar2")
    t0 = time.perf_counter()
    data = module.simulate(args.seed, n=args.samples)
    print(f"simulated {args.samples} samples in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    est = casest.estimate(module.model(), data, progress=True)
    print(est.report())
    return 0 if est.success else 1


if __name__ == "__main__":
    sys.exit(main())
