#!/usr/bin/env python3
"""What a time delay costs an output-error estimate, on the AP2 rate responses (real record,
two segments, jittered time stamps): the same model without a delay, with one input delay on
the deflections, and with one output delay on the measured rates, each cold (first estimate
in the process, the compile cache as it is) and warm (best of ``--repeats``), as ratios to the
undelayed estimate measured in the same process.

    python3 scripts/benchmarks/bench_delays.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402


def timed(module, delay: str | None, repeats: int) -> tuple:
    model, records = module.model(delay), module.segments(delay=delay)
    times, est = [], None
    for _ in range(1 + repeats):
        t0 = time.perf_counter()
        est = casest.estimate(model, records, sweep_settings=module.SWEEP_SETTINGS)
        times.append(time.perf_counter() - t0)
    return times[0], min(times[1:]), est


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    module = casest.load_model_file("ampyx_rates")
    rows = {delay: timed(module, delay, args.repeats) for delay in (None, "input", "output")}
    base_cold, base_warm, _ = rows[None]
    print(f"{'delay':>8} {'cold s':>8} {'warm s':>8} {'cold ratio':>11} {'warm ratio':>11} {'stage 1 s':>10} "
          f"{'stage 2 s':>10} {'iterations':>10} {'tau (s)':>9}")
    for delay, (cold, warm, est) in rows.items():
        tau = est.values.get("tau", float("nan"))
        print(f"{str(delay):>8} {cold:8.2f} {warm:8.2f} {cold / base_cold:11.2f} {warm / base_warm:11.2f} "
              f"{est.timings['stage1']:10.2f} {est.timings['stage2']:10.2f} {est.n_iterations:10d} {tau:9.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
