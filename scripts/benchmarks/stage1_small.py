#!/usr/bin/env python3
"""Stage 1 below the compile threshold (N x K < ``SweepSettings.jit_min_work``) against the NumPy peer.

    python3 scripts/benchmarks/stage1_small.py [--runs 7] [--cache filled|empty]

The Pitot sweep (Tr[R] at K random candidates over N samples, xi1 unconstrained) by casest's
default stage-1 evaluator (``GramEvaluator`` with ``SweepSettings()``'s compile decision, one
thread) and by the NumPy peer of ``stage1_peers.py`` (the algebra reduced by hand to BLAS products,
chunks of 8 candidates, one thread), after each one's build, interleaved in one process with the
order alternated, CPU time (``time.process_time``), each timing over enough repetitions for about
2e6 candidate-samples; median and range of the ratio NumPy / casest over ``--runs`` runs. With
``--cache filled`` (default) the compile cache holds the Gram sums' library (one sweep at N K =
1e6 builds it first, untimed): casest uses it at every size; with ``--cache empty`` (a fresh cache
folder) it sums in NumPy operations, compiling nothing.
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", ".."))

SIZES = ((100, 100), (1000, 100), (100, 1000), (1000, 1000))


def _cpu_per_call(fun, reps: int) -> float:
    t = time.process_time()
    for _ in range(reps):
        fun()
    return (time.process_time() - t) / reps


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--cache", choices=["filled", "empty"], default="filled")
    args = parser.parse_args(argv)
    if args.cache == "empty":
        os.environ["CASEST_CACHE_DIR"] = tempfile.mkdtemp(prefix="casest_empty_cache_")
    import casest
    import stage1_peers as peers
    from bench_common import pitot_data
    from bench_stage1 import pitot_sweep_inputs
    from casest.backend.lane_sums import LaneSum
    from casest.two_stage.sweep.candidates import draw_candidates
    from casest.two_stage.sweep.evaluators import GramEvaluator, evaluate_candidates

    if args.cache == "filled":  # one sweep at the threshold compiles the Gram sums (untimed)
        module, model, data = pitot_data(1000)
        part = casest.separate(model)
        GramEvaluator(part, data, 1000, jit=True)
    print(f"Pitot sweep, one thread, compile cache {args.cache}, {args.runs} runs, CPU time, "
          f"{datetime.date.today()}, load {os.getloadavg()[0]:.2f}")
    for n, k in SIZES:
        module, model, data = pitot_data(n)
        part = casest.separate(model)
        cands, _, _ = draw_candidates(model, part, casest.SweepSettings(design="random", n_candidates=k, seed=1))
        ours = GramEvaluator(part, data, k, jit=casest.SweepSettings().resolved_jit(n, k), threads=1,
                             cached=True)  # as SweepSettings()'s jit=None asks
        peer = peers.NumpySweep(peers.peer_inputs(pitot_sweep_inputs(module, data)), chunk=8)
        evaluate_candidates(ours, data.outputs, cands)
        peer.trace(cands, 1)
        reps = max(1, int(2e6 // (n * k)))
        ratios = []
        for run in range(args.runs):
            first, second = ("ours", "peer") if run % 2 == 0 else ("peer", "ours")
            times = {}
            for who in (first, second):
                call = (lambda: evaluate_candidates(ours, data.outputs, cands)) if who == "ours" else \
                    (lambda: peer.trace(cands, 1))
                times[who] = _cpu_per_call(call, reps)
            ratios.append(times["peer"] / times["ours"])
        path = "compiled sums" if isinstance(ours._lanes, LaneSum) else "NumPy sums"
        print(f"  N = {n}, K = {k} (N K = {n * k:.0e}, {path}): NumPy / casest {np.median(ratios):.2f} "
              f"({min(ratios):.2f}-{max(ratios):.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
