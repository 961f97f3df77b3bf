#!/usr/bin/env python3
"""The streamed stage 1 on a dask.distributed LocalCluster: memory against the design's size, the
same best candidates as the local sweep, a worker killed mid-sweep, an interrupted sweep resumed.

    python3 scripts/benchmarks/bench_streamed_sweep.py [--n 500] [--sizes 100000 1000000 10000000] [--task-size 50000]

The Pitot sweep (``models/pitot5hole.py``, the first N samples of the simulated flight, the
random design of seed 7) with ``casest.two_stage.sweep.streamed.streamed_sweep`` on a
LocalCluster of 2 worker processes with one thread each, keeping the 64 best candidates:

1. each design size in turn: wall time, the driver's peak RSS above its RSS before the sweep
   (Linux ``VmHWM``, reset before it) and each worker's peak RSS (reset before it too);
2. 1e5 candidates: the streamed sweep's best candidates against the local ``casest.sweep`` of the
   same design (the first 64 by Tr[R], candidates and R equal);
3. 1e6 candidates again, a worker process killed (SIGKILL) once a quarter of the tasks have
   finished: the nanny restarts it, the scheduler runs its tasks again, and the result equals
   the undisturbed run's;
4. 1e6 candidates with a store, in a child process killed (SIGKILL) once a third of the tasks
   are stored; then the same call again: it loads the stored tasks, runs the others, and equals
   the undisturbed run's.

From the measured time per candidate and worker it restates what a 1e8-candidate sweep on 64
workers would take at N = 1e4 (the rate at N = 1e4 is measured here too, on 1e5 candidates).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402
from casest.two_stage.sweep.streamed import streamed_sweep  # noqa: E402

KEEP, SEED = 64, 7


def _status_mib(field: str) -> float:
    with open("/proc/self/status", encoding="ascii") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith(field)) / 1024


def _reset_peak() -> float:
    with open("/proc/self/clear_refs", "w", encoding="ascii") as fh:
        fh.write("5")
    return _status_mib("VmRSS")


def _worker_reset() -> float:
    return _reset_peak()


def _worker_peak() -> float:
    return _status_mib("VmHWM")


def pitot(n: int):
    module = casest.load_model_file("pitot5hole")
    return module.model(), module.simulate(0).subset(slice(0, n))


def settings_for(size: int, task_size: int, scheduler=None) -> casest.SweepSettings:
    return casest.SweepSettings(design="random", n_candidates=size, seed=SEED, task_size=task_size, scheduler=scheduler)


def sizes_table(client, model, data, sizes, task_size: int, say) -> dict:
    """Wall time and peak memory per design size; the results by size."""
    say("| candidates | tasks | wall s | us per candidate and worker | driver peak above its RSS MiB | "
        "worker peak MiB (each) | best Tr[R] |")
    say("|---|---|---|---|---|---|---|")
    results, walls = {}, {}
    for size in sizes:
        client.run(_worker_reset)
        before = _reset_peak()
        t = time.perf_counter()
        result = streamed_sweep(model, data, settings_for(size, task_size, client), keep=KEEP)
        wall = time.perf_counter() - t
        driver = _status_mib("VmHWM") - before
        workers = sorted(client.run(_worker_peak).values())
        results[size], walls[size] = result, wall
        say(f"| {size:.0e} | {len(result.task_best)} | {wall:.1f} | {2 * wall / size * 1e6:.2f} | {driver:.0f} | "
            f"{', '.join(f'{w:.0f}' for w in workers)} | {result.ranking[0]:.6g} |")
    say()
    return results, walls


def killed_worker(client, model, data, size: int, task_size: int, reference, reference_wall: float, say) -> None:
    """Kill a worker process a quarter of the way through (by the undisturbed run's time); the
    result must equal the reference."""
    victim = sorted(client.run(os.getpid).values())[0]
    n_tasks = -(-size // task_size)
    killer = threading.Timer(0.25 * reference_wall, os.kill, (victim, signal.SIGKILL))
    killer.start()
    t = time.perf_counter()
    result = streamed_sweep(model, data, settings_for(size, task_size, client), keep=KEEP)
    wall = time.perf_counter() - t
    killer.join()
    same = np.array_equal(result.indices, reference.indices) and np.array_equal(result.R, reference.R)
    say(f"Worker killed (SIGKILL, pid {victim}) a quarter of the way through the {n_tasks} tasks of a {size:.0e}-candidate "
        f"sweep: finished in {wall:.1f} s (undisturbed: {reference_wall:.1f} s) with {result.n_evaluated} candidates "
        f"evaluated; best candidates equal to the undisturbed run's: {'yes' if same else 'NO'}.")
    say()


CHILD = """
import sys
sys.path.insert(0, sys.argv[1])
from bench_streamed_sweep import pitot, settings_for
from casest.two_stage.sweep.streamed import streamed_sweep
model, data = pitot(int(sys.argv[2]))
streamed_sweep(model, data, settings_for(int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]), store=sys.argv[6], keep=64)
"""


def interrupted(address: str, model, data, n: int, size: int, task_size: int, reference, say) -> None:
    """Kill the driver once a third of the tasks are stored, then resume with the same call."""
    n_tasks = -(-size // task_size)
    with tempfile.TemporaryDirectory(prefix="casest_streamed_store_") as store:
        here = os.path.dirname(os.path.abspath(__file__))
        child = subprocess.Popen([sys.executable, "-c", CHILD, here, str(n), str(size), str(task_size), address, store])
        while child.poll() is None and sum(f.startswith("task_") for f in os.listdir(store)) < n_tasks // 3:
            time.sleep(0.2)
        child.send_signal(signal.SIGKILL)
        child.wait()
        stored = sum(f.startswith("task_") for f in os.listdir(store))
        t = time.perf_counter()
        result = streamed_sweep(model, data, settings_for(size, task_size, address), store=store, keep=KEEP)
        wall = time.perf_counter() - t
    same = np.array_equal(result.indices, reference.indices) and np.array_equal(result.R, reference.R)
    say(f"Driver killed (SIGKILL) with {stored} of {n_tasks} tasks stored; the same call again loaded "
        f"{result.tasks_loaded}, ran {result.tasks_run} in {wall:.1f} s; best candidates equal to the undisturbed "
        f"run's: {'yes' if same else 'NO'}.")
    say()


def bench(n: int, sizes: list, task_size: int, say=print) -> None:
    from distributed import Client, LocalCluster

    model, data = pitot(n)
    say(f"Pitot sweep, N = {n}, random design (seed {SEED}), tasks of {task_size} candidates, the {KEEP} best kept; "
        "LocalCluster of 2 worker processes, 1 thread each.")
    say()
    with LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=None) as cluster, \
            Client(cluster) as client:
        results, walls = sizes_table(client, model, data, sizes, task_size, say)
        local = casest.sweep(model, data, settings=settings_for(100000, task_size))
        order = np.argsort(local.trace_R[:100000], kind="stable")[:KEEP]
        streamed = results.get(100000) or streamed_sweep(model, data, settings_for(100000, task_size, client), keep=KEEP)
        same = np.array_equal(streamed.candidates, local.candidates[order]) and np.array_equal(streamed.R, local.R[order])
        say(f"1e5 candidates: the {KEEP} best of the streamed sweep equal the local casest.sweep's first {KEEP} by "
            f"Tr[R] (candidates and R): {'yes' if same else 'NO'}.")
        say()
        if 1000000 not in results:
            t = time.perf_counter()
            results[1000000] = streamed_sweep(model, data, settings_for(1000000, task_size, client), keep=KEEP)
            walls[1000000] = time.perf_counter() - t
        reference = results[1000000]
        killed_worker(client, model, data, 1000000, task_size, reference, walls[1000000], say)
        interrupted(cluster.scheduler_address, model, data, n, 1000000, task_size, reference, say)
        big, big_data = pitot(10000)
        t = time.perf_counter()
        streamed_sweep(big, big_data, settings_for(100000, 5000, client), keep=KEEP)
        per = 2 * (time.perf_counter() - t) / 100000
        say(f"At N = 1e4: {per * 1e6:.0f} us per candidate and worker (1e5 candidates, tasks of 5000, first run "
            f"included). A 1e8-candidate sweep on 64 such workers: about {1e8 * per / 64 / 60:.0f} min at that rate, "
            f"if it scales linearly (this 2-core machine cannot check beyond two workers); the driver keeps "
            f"{KEEP} candidates and 3 numbers per task.")
        say()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=500)
    parser.add_argument("--sizes", type=int, nargs="+", default=[100000, 1000000, 10000000])
    parser.add_argument("--task-size", type=int, default=50000)
    args = parser.parse_args(argv)
    bench(args.n, args.sizes, args.task_size)
    return 0


if __name__ == "__main__":
    sys.exit(main())
