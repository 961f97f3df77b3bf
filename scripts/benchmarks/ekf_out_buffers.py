#!/usr/bin/env python3
"""The EKF's compiled pass written into an earlier result's arrays (``filter(data, out=...)``)
against a pass with fresh arrays and against the numba loop EKF (``ekf_numba_peer.py``).

    python3 scripts/benchmarks/ekf_out_buffers.py [--runs 7] [--samples 100000 1000000]

The pendulum record of ``bench_filters.py``; after a first call of each (builds, numba's compile),
the three contenders run in one process, interleaved, the order reversed at every run, each timed
with the process's CPU clock (``time.process_time``); the fresh pass's result is freed at once.
Prints the median and range of casest / numba per contender, with the date and the load.
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", ".."))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--samples", type=int, nargs="+", default=[100000, 1000000])
    args = parser.parse_args(argv)
    import bench_filters as bf
    import ekf_numba_peer
    from casest.filters.ekf import ExtendedKalmanFilter

    if not ekf_numba_peer.available():
        raise SystemExit("needs numba (pip install numba)")
    model, loop = bf.pendulum(), ekf_numba_peer.ekf_pass_factory()
    print(f"EKF over the pendulum record, {args.runs} runs, CPU time, {datetime.date.today()}, "
          f"load {os.getloadavg()[0]:.2f}")
    for n in args.samples:
        data = bf.record(model, n, 2)
        ekf = ExtendedKalmanFilter(model, bf.THETA, {"rate": bf.Q_RATE}, [bf.R_VAR] * 2, bf.P0)
        peer_args = (np.ascontiguousarray(data.outputs), np.ascontiguousarray(data.signals[:, 1]), bf.THETA["c"],
                     bf.THETA["L"], bf.Q_RATE, bf.R_VAR, float(bf.P0[0, 0]))
        earlier = ekf.filter(data)
        loop(*peer_args)
        calls = {"fresh": lambda: ekf.filter(data) and None, "out": lambda: ekf.filter(data, out=earlier),
                 "numba": lambda: loop(*peer_args)}
        ratios = {"fresh": [], "out": []}
        for run in range(args.runs):
            seconds = {}
            for who in (list(calls) if run % 2 == 0 else list(reversed(calls))):
                t = time.process_time()
                calls[who]()
                seconds[who] = time.process_time() - t
            for who in ratios:
                ratios[who].append(seconds[who] / seconds["numba"])
        text = "; ".join(f"{'fresh arrays' if who == 'fresh' else 'out='} / numba {np.median(r):.2f} "
                         f"({min(r):.2f}-{max(r):.2f})" for who, r in ratios.items())
        print(f"  N = {n}: {text}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
