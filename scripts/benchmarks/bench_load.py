#!/usr/bin/env python3
"""Wall time against CPU time on a busy machine: casest's single-threaded passes beside a numba loop.

    python3 scripts/benchmarks/bench_load.py [--load 2] [--n 1000 10000 100000] [--repeats 7]

Starts ``--load`` CPU-bound processes (pure Python loops), then times, in this process, each
contender ``--repeats`` times, the contenders taking turns within each repeat: wall time (``perf_counter``) and this process's CPU time
(``process_time``, all its threads). A single-threaded computation that never waits has
wall / CPU near 1 on an idle machine; beside two CPU-bound processes on two cores the
scheduler gives it a fair share of a core, and wall / CPU rises towards 1.5 for any such
process once it runs longer than a scheduling slice (a few milliseconds): the numba loop
is the reference for what the machine gives. A pass that waited (thread hand-offs, a
spinning pool) would show wall / CPU above the numba loop's at the same duration, or CPU
time above the idle run's.

Contenders: the EKF's compiled pass (``ExtendedKalmanFilter.filter``, the pendulum of
``bench_filters.py``) and the numba loop EKF (``ekf_numba_peer.py``) at each N; stage 2
alone on NIST Gauss1 (Levenberg-Marquardt, warm, compiled residuals) as a small static
solve. Prints one row per contender and N: median wall and CPU (ms) and the median and
range of wall / CPU over the repeats, then the same without the load.
"""

from __future__ import annotations

import argparse
import glob
import multiprocessing as mp
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", ".."))


def _burn(stop) -> None:
    x = 0
    while not stop.is_set():
        for i in range(100_000):
            x += i


def _timed_interleaved(runs, repeats: int) -> list:
    """(label, [(wall, CPU) per repeat]) of every contender, the contenders taking turns within each
    repeat: run one after the other, a block of one contender's repeats can fall in a stretch where
    the scheduler placed this process alone on a core and another's where it shares one."""
    times = {label: [] for label, _ in runs}
    for _ in range(repeats):
        for label, fun in runs:
            w, c = time.perf_counter(), time.process_time()
            fun()
            times[label].append((time.perf_counter() - w, time.process_time() - c))
    return [(label, times[label]) for label, _ in runs]


def contenders(sizes) -> list:
    """(label, callable) of every contender, each called once (built, compiled, warm)."""
    import bench_filters as bf
    import ekf_numba_peer
    import casest
    from casest.apps.nist import read_nist
    from casest.backend.ipopt import SolverSettings
    from casest.filters.ekf import ExtendedKalmanFilter
    from casest.two_stage.solve.levenberg_marquardt import prediction_function

    out = []
    model = bf.pendulum()
    loop = ekf_numba_peer.ekf_pass_factory() if ekf_numba_peer.available() else None
    for n in sizes:
        data = bf.record(model, n, 2)
        ekf = ExtendedKalmanFilter(model, bf.THETA, {"rate": bf.Q_RATE}, [bf.R_VAR] * 2, bf.P0)
        out.append((f"casest EKF pass, N = {n}", lambda ekf=ekf, data=data: ekf.filter(data)))
        if loop is not None:
            args = (np.ascontiguousarray(data.outputs), np.ascontiguousarray(data.signals[:, 1]), bf.THETA["c"],
                    bf.THETA["L"], bf.Q_RATE, bf.R_VAR, float(bf.P0[0, 0]))
            out.append((f"numba loop EKF, N = {n}", lambda args=args: loop(*args)))
    path = glob.glob(os.path.join(HERE, "..", "..", "data", "nist_strd", "Gauss1.dat"))[0]
    pr = read_nist(path, start=1)
    start = np.clip(pr.model.nominal, pr.model.lower_bounds, pr.model.upper_bounds)
    casest.solve_stage2(pr.model, pr.data, start, mode="full")
    prediction_function(pr.model, pr.data.n_samples, SolverSettings()).compile_now()
    out.append(("casest stage 2 alone, NIST Gauss1", lambda: casest.solve_stage2(pr.model, pr.data, start, mode="full")))
    for _, fun in out:
        fun()
    return out


def table(rows: list, load: int, repeats: int) -> None:
    print(f"\n{load} CPU-bound process(es) beside this one, {os.cpu_count()} cores, {repeats} repeats:\n")
    print("| contender | wall ms (median) | CPU ms (median) | wall / CPU median | wall / CPU range |")
    print("|---|---|---|---|---|")
    for label, times in rows:
        wall, cpu = np.array([w for w, _ in times]), np.array([c for _, c in times])
        ratio = wall / np.maximum(cpu, 1e-9)
        print(f"| {label} | {np.median(wall) * 1e3:.2f} | {np.median(cpu) * 1e3:.2f} | {np.median(ratio):.2f} | "
              f"{ratio.min():.2f}-{ratio.max():.2f} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--load", type=int, default=2)
    parser.add_argument("--n", type=int, nargs="+", default=[1000, 10000, 100000])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    runs = contenders(args.n)
    for load in (args.load, 0):
        stop = mp.Event()
        burners = [mp.Process(target=_burn, args=(stop,)) for _ in range(load)]
        for p in burners:
            p.start()
        time.sleep(1.0 if load else 0.0)
        try:
            rows = _timed_interleaved(runs, args.repeats)
        finally:
            stop.set()
            for p in burners:
                p.join()
        table(rows, load, args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
