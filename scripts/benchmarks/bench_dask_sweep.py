#!/usr/bin/env python3
"""Stage 1 on a dask.distributed LocalCluster: the speed-up of 1 and 2 workers, and what a big sweep would take.

    python3 scripts/benchmarks/bench_dask_sweep.py [--n 10000] [--k 20000] [--task-size 2000]

The Pitot sweep (models/pitot5hole.py, the first N samples of the simulated flight, K random
candidates). Timed in one process: the local evaluation of all candidates with one thread and
with the default threads, then the same candidates on a LocalCluster of 1 and of 2 worker
processes (one thread each): a first run (workers build or load the compiled evaluator) and a
second (built). Every result is checked equal to the local one. From the measured time per
candidate of one worker (second run), the estimate of a 1e8-candidate sweep on 64 such workers
assumes linear scaling plus the measured per-task overhead.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402
from casest.two_stage.sweep.distributed import evaluate_on_cluster  # noqa: E402
from casest.two_stage.sweep.evaluators import evaluate_candidates  # noqa: E402
from casest.two_stage.sweep.orchestration import candidate_evaluator, linear_parameter_bounds  # noqa: E402
from casest.two_stage.sweep.candidates import draw_candidates  # noqa: E402


def bench(n: int, k: int, task_size: int, say=print) -> None:
    """Time the sweep locally and on LocalClusters of 1 and 2 workers; write the table with ``say``."""
    from distributed import LocalCluster

    module = casest.load_model_file("pitot5hole")
    model = module.model()
    full = module.simulate(0)
    data = full.subset(np.arange(min(n, full.n_samples)))
    part = casest.separate(model)
    settings = casest.SweepSettings(design="random", n_candidates=k, seed=1, task_size=task_size)
    cands, _, _ = draw_candidates(model, part, settings)
    bounds = linear_parameter_bounds(model, part)
    rows, reference = [], None
    for threads in (1, None):
        ev = candidate_evaluator(model, part, data, replace(settings, threads=threads), len(cands))
        t = time.perf_counter()
        out = evaluate_candidates(ev, data.outputs, cands, *bounds)
        rows.append((f"local, {ev.threads if hasattr(ev, 'threads') else 1} thread(s)", time.perf_counter() - t, out))
        reference = reference or out
    for workers in (1, 2):
        with LocalCluster(n_workers=workers, threads_per_worker=1, host="127.0.0.1", dashboard_address=None) as cl:
            s = replace(settings, scheduler=cl.scheduler_address)
            for label in ("first", "second"):
                t = time.perf_counter()
                out = evaluate_on_cluster(candidate_evaluator, model, part, data, s, cands, bounds)
                rows.append((f"LocalCluster, {workers} worker(s), {label} run", time.perf_counter() - t, out))
    base = rows[0][1]
    say(f"The Pitot sweep, N = {data.n_samples}, K = {len(cands)} random candidates, tasks of {task_size}, on a "
        "`LocalCluster` of worker processes with one thread each (a first run builds or loads the compiled "
        "evaluator in the workers; the second reuses it):")
    say()
    say("| run | time s | speed-up over local 1 thread | equal to local |")
    say("|---|---|---|---|")
    for name, seconds, out in rows:
        equal = all(np.array_equal(a, b, equal_nan=True) for a, b in zip(out, reference))
        say(f"| {name} | {seconds:.2f} | {base / seconds:.2f} | {'yes' if equal else 'NO'} |")
    one_worker = [r for r in rows if r[0] == "LocalCluster, 1 worker(s), second run"][0][1]
    per_candidate = one_worker / len(cands)  # s per candidate of one worker at this N, overhead included
    big = 1e8 * per_candidate / 64
    say()
    say(f"One worker: {per_candidate * 1e6:.1f} us per candidate at N = {data.n_samples} (tasks and transfers "
        f"included). A 1e8-candidate sweep on 64 such workers: about {big:.0f} s ({big / 3600:.2f} h) at this N, "
        f"if it scales linearly (this 2-core machine cannot check beyond two workers); the candidates (1e8 x "
        f"{cands.shape[1]} doubles, {1e8 * cands.shape[1] * 8 / 1e9:.0f} GB) and their results would be drawn and "
        "kept in blocks, not at once.")
    say()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=10000, help="samples")
    parser.add_argument("--k", type=int, default=20000, help="candidates")
    parser.add_argument("--task-size", type=int, default=2000, help="candidates per task")
    args = parser.parse_args(argv)
    bench(args.n, args.k, args.task_size)
    return 0


if __name__ == "__main__":
    sys.exit(main())
