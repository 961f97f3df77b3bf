#!/usr/bin/env python3
"""Re-solving a built ML solver on new data against building and solving afresh.

    python3 scripts/benchmarks/bench_resolve.py [--models scalar2 pitot5hole] [--repeats 3] [--jit]

For each model, in this one process: build the stage-2 problem (casest.interop.embed.ml_problem)
and its IPOPT solver and solve data set A (fresh: build + solve), then re-solve the same
solver on data set B of the same length (re-solve: solve only). Prints the median times
and their ratio re-solve / (build + solve).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import numpy as np  # noqa: E402

import casest  # noqa: E402
from casest.interop import ml_problem  # noqa: E402


def datasets(module, seed):
    data = module.simulate(seed)
    return module.stage_data(data)[1] if hasattr(module, "stage_data") else data


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", nargs="+", default=["scalar2", "pitot5hole"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--jit", action="store_true", help="compile the NLP (build includes the compile)")
    args = parser.parse_args(argv)
    settings = casest.SolverSettings(jit=args.jit)
    print(f"{'model':>12} {'N':>6} {'build+solve s':>14} {'re-solve s':>11} {'ratio':>7}")
    for name in args.models:
        module = casest.load_model_file(name)
        model = module.model()
        data_a, data_b = datasets(module, 100), datasets(module, 101)
        start = model.vector(module.TRUTH) if hasattr(module, "TRUTH") else model.nominal
        fresh, resolve = [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            prob = ml_problem(model, data_a.n_samples)
            solver = prob.solver(settings)
            lbx, ubx = prob.bounds(data_a, settings)
            x0 = prob.x0(start, np.var(data_a.outputs, axis=0))
            solver(x0=x0, p=prob.data_vector(data_a), lbx=lbx, ubx=ubx)
            fresh.append(time.perf_counter() - t0)
            lbx, ubx = prob.bounds(data_b, settings)
            t0 = time.perf_counter()
            solver(x0=x0, p=prob.data_vector(data_b), lbx=lbx, ubx=ubx)
            resolve.append(time.perf_counter() - t0)
        f, r = statistics.median(fresh), statistics.median(resolve)
        print(f"{name:>12} {data_a.n_samples:>6} {f:>14.3f} {r:>11.3f} {r / f:>7.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
