#!/usr/bin/env python3
"""CPU time of filter-error ML's three formulations on a practice-size turbulent record.

    python3 scripts/benchmarks/bench_practice_filter_error.py [--repeats 5] [--out FILE.md]

The record is ``models/turbulent_longitudinal.py`` seed 1 (4 states, 11 coefficients, 4
process-noise distributions, 7 channels, 601 samples at 10 Hz; the size of the flight-test
textbook's turbulent longitudinal record), estimated from the model file's ``START`` as a user
calls it, with the Fisher-information std. Each repeat runs each formulation in a fresh
process: a first estimate (cold: the graphs and compiled loops built, the compile cache
emptied before the process starts) and a second in the same process (warm). Reported: the
process's CPU seconds (all threads; ``time.process_time``), median and range over the
repeats, with the outcome of the first repeat, the date and the load average.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
FORMS = ("innovation", "steady-state", "time-varying")


def child(formulation: str) -> dict:
    sys.path.insert(0, os.path.join(HERE, "..", ".."))
    import casest

    mf = casest.load_model_file(os.path.join(HERE, "..", "..", "models", "turbulent_longitudinal.py"))
    model, data = mf.model(), mf.simulate(1)
    out = {}
    for label in ("cold", "warm"):
        t0 = time.process_time()
        fe = casest.filter_error_estimate(model, data, mf.TURBULENCE_START, start=mf.START, formulation=formulation,
                                          covariance="fisher")
        out[label] = {"cpu": time.process_time() - t0, "success": bool(fe.success), "status": fe.status,
                      "iterations": int(fe.n_iterations), "rounds": int(fe.n_rounds),
                      "C_mq": float(fe.values["C_mq"]), "C_mq_std": float(fe.stds["C_mq"] or np.nan)}
    return out


def run_child(formulation: str) -> dict:
    cache = tempfile.mkdtemp(prefix="casest_bench_pfe_")
    try:
        env = dict(os.environ, CASEST_CACHE_DIR=cache)
        out = subprocess.run([sys.executable, os.path.abspath(__file__), "--child", formulation], capture_output=True,
                             text=True, env=env)
        if out.returncode != 0:
            raise RuntimeError(f"the {formulation} run failed:\n{out.stderr[-3000:]}")
        return json.loads(out.stdout.strip().splitlines()[-1])
    finally:
        shutil.rmtree(cache, ignore_errors=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", help="also write the table (Markdown) here")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child)))
        return 0
    load_before = os.getloadavg()
    runs = {form: [] for form in FORMS}
    for _ in range(args.repeats):
        for form in FORMS:  # interleaved: a drift of the machine's load reaches every formulation alike
            runs[form].append(run_child(form))
    lines = [f"{time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores, load average {load_before[0]:.2f} before and "
             f"{os.getloadavg()[0]:.2f} after; {args.repeats} repeats, CPU seconds median (min-max):", "",
             "| formulation | cold CPU s | warm CPU s | success | status | rounds | iterations | C_mq +/- std |",
             "|---|---|---|---|---|---|---|---|"]
    for form in FORMS:
        cold = np.array([r["cold"]["cpu"] for r in runs[form]])
        warm = np.array([r["warm"]["cpu"] for r in runs[form]])
        first = runs[form][0]["cold"]
        lines.append(f"| {form} | {np.median(cold):.2f} ({cold.min():.2f}-{cold.max():.2f}) | "
                     f"{np.median(warm):.2f} ({warm.min():.2f}-{warm.max():.2f}) | {first['success']} | "
                     f"{first['status']} | {first['rounds'] or '-'} | {first['iterations']} | "
                     f"{first['C_mq']:.3f} +/- {first['C_mq_std']:.3f} |")
    for line in lines:
        print(line)
    if args.out:
        sys.path.insert(0, os.path.join(HERE, "..", ".."))
        from casest.data.dataset import atomic_write_text

        atomic_write_text(args.out, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
