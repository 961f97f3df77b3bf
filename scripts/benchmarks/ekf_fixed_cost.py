#!/usr/bin/env python3
"""Where a short record's EKF pass spends its time: the whole ``filter`` call against the layers
beneath it, down to the compiled loop's call.

    python3 scripts/benchmarks/ekf_fixed_cost.py [--samples 3 100] [--calls 5000] [--repeats 7]

The pendulum of ``bench_filters.py`` on records of a few samples, the loop compiled before timing.
Each layer is called ``--calls`` times in a row, ``--repeats`` times, the layers interleaved;
printed: the fastest repeat's CPU time per call (``time.process_time``) in microseconds, and the
numba loop EKF's (``ekf_numba_peer.py``, when numba is installed) for scale. Layers:

- ``filter``: ``ExtendedKalmanFilter.filter(data)``, as a user calls it;
- ``ekf_pass``: the arrays of the pass (``casest.filters.compiled_passes.ekf_pass``): without the
  argument checks, the initial state and the ``FilterResult``;
- ``run_record``: the loop's call through ``run_record`` with the constants made: without the
  record's rows, the constants, the likelihood check and the result's views;
- ``loop``: the ``RecordLoop`` call alone (its arrays, addresses and ctypes call, and the C loop).
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

#: the EKF pass's record fields: x(k|k), vec P(k|k), e, vec S, ll, iterations, vec Phi (2 states, 2 outputs)
WIDTHS = (2, 4, 2, 4, 1, 1, 4)


def layers(n_samples: int) -> dict:
    """The timed calls on a pendulum record of ``n_samples`` samples, by layer."""
    import bench_filters as bf
    from casest._casadi.record_loop import RecordLoop, RecordRows
    from casest.filters.compiled_passes import ekf_pass, ekf_sample_function, run_record
    from casest.filters.ekf import ExtendedKalmanFilter

    model = bf.pendulum()
    ekf = ExtendedKalmanFilter(model, bf.THETA, {"rate": bf.Q_RATE}, [bf.R_VAR] * 2, bf.P0)
    t = np.arange(n_samples) * bf.DT
    data = model.dataset({"t": t, "torque": 0.0 * t, "px": np.sin(t), "py": -np.cos(t)}, for_estimation=False)
    step = ekf_sample_function(ekf)
    loop = RecordLoop.build(step, WIDTHS, last_entry_first=True, signal_rows=(2, 1))  # compiles or loads it
    if loop is None:
        raise SystemExit("needs a C compiler")
    ekf.filter(bf.record(model, 2000, 2), compiled=True)  # the pass's own loop, compiled (or found) once
    x0 = np.array([1.0, 0.0])
    c = np.concatenate([ekf.theta, ekf.Qc.reshape(-1, order="F"), ekf.input_noise, ekf.R.reshape(-1, order="F")])
    acc0 = np.concatenate([x0, ekf.P0.reshape(-1, order="F")])
    rows = RecordRows(data.outputs, data.signals)
    return {"filter": lambda: ekf.filter(data), "ekf_pass": lambda: ekf_pass(ekf, data, x0),
            "run_record": lambda: run_record(step, acc0, rows, c, compiled=True, widths=WIDTHS),
            "loop": lambda: loop(acc0, rows, c)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, nargs="+", default=[3, 100])
    parser.add_argument("--calls", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    import bench_filters as bf
    import ekf_numba_peer

    print(f"EKF pass by layer, CPU us per call (fastest of {args.repeats} x {args.calls} calls), "
          f"{datetime.datetime.now().isoformat(timespec='minutes')}, load {os.getloadavg()[0]:.2f}")
    for n in args.samples:
        calls = layers(n)
        if ekf_numba_peer.available():
            data = bf.record(bf.pendulum(), max(n, 5), 2)
            Y, U = np.ascontiguousarray(data.outputs[:n]), np.ascontiguousarray(data.signals[:n, 1])
            nb = ekf_numba_peer.ekf_pass_factory()
            args_nb = (Y, U, bf.THETA["c"], bf.THETA["L"], bf.Q_RATE, bf.R_VAR, float(bf.P0[0, 0]))
            nb(*args_nb)
            calls["numba loop"] = lambda: nb(*args_nb)
        best = {name: float("inf") for name in calls}
        for _ in range(args.repeats):
            for name, call in calls.items():
                c0 = time.process_time()
                for _ in range(args.calls):
                    call()
                best[name] = min(best[name], (time.process_time() - c0) / args.calls)
        print(f"N = {n}: " + ", ".join(f"{name} {seconds * 1e6:.1f}" for name, seconds in best.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
