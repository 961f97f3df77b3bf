#!/usr/bin/env python3
"""CPU time of filter-error ML's three formulations on a practice-size turbulent record.

    python3 scripts/benchmarks/bench_practice_filter_error.py [--repeats 5] [--out FILE.md]

The record is ``models/turbulent_longitudinal.py`` seed 1 (4 states, 11 coefficients, 4
process-noise distributions, 7 channels, 601 samples at 10 Hz; the size of the flight-test
textbook's turbulent longitudinal record), estimated from the model file's ``START`` as a user
calls it, and again from the simulated truth (coefficients and intensities), with the
Fisher-information std. Each repeat runs each formulation in a fresh
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
#: where each estimate starts: the model file's START (as a user calls it) or the simulated truth
STARTS = {"start": "START", "truth": "the truth"}


def child(formulation: str, start: str) -> dict:
    sys.path.insert(0, os.path.join(HERE, "..", ".."))
    import casest

    mf = casest.load_model_file(os.path.join(HERE, "..", "..", "models", "turbulent_longitudinal.py"))
    model, data = mf.model(), mf.simulate(1)
    out = {}
    for label in ("cold", "warm"):
        t0 = time.process_time()
        theta0, noise0 = (mf.START, mf.TURBULENCE_START) if start == "start" else (mf.TRUTH, mf.TURBULENCE)
        fe = casest.filter_error_estimate(model, data, noise0, start=theta0, formulation=formulation,
                                          covariance="fisher")
        out[label] = {"cpu": time.process_time() - t0, "success": bool(fe.success), "status": fe.status,
                      "iterations": int(fe.n_iterations), "rounds": int(fe.n_rounds),
                      "C_mq": float(fe.values["C_mq"]), "C_mq_std": float(fe.stds["C_mq"] or np.nan)}
    return out


def run_child(formulation: str, start: str) -> dict:
    cache = tempfile.mkdtemp(prefix="casest_bench_pfe_")
    try:
        env = dict(os.environ, CASEST_CACHE_DIR=cache)
        out = subprocess.run([sys.executable, os.path.abspath(__file__), "--child", formulation, start],
                             capture_output=True,
                             text=True, env=env)
        if out.returncode != 0:
            raise RuntimeError(f"the {formulation} run failed:\n{out.stderr[-3000:]}")
        return json.loads(out.stdout.strip().splitlines()[-1])
    finally:
        shutil.rmtree(cache, ignore_errors=True)


def bench(repeats: int, say=print) -> None:
    """The three formulations from both starts, ``repeats`` fresh processes each, interleaved."""
    load_before = os.getloadavg()
    runs = {(form, start): [] for start in STARTS for form in FORMS}
    for _ in range(repeats):
        for key in runs:  # interleaved: a drift of the machine's load reaches every configuration alike
            runs[key].append(run_child(*key))
    say("## Filter error on a practice-size turbulent record")
    say()
    say("`models/turbulent_longitudinal.py` seed 1: 4 states, 11 coefficients, 4 process-noise distributions, 7 "
        "channels, 601 samples (the size of the flight-test textbook's turbulent longitudinal record); each "
        "configuration in a fresh process with an empty compile cache (cold: the first estimate; warm: a second in "
        "that process); CPU seconds of the process (all threads), median (min-max) over "
        f"{repeats} repeats, {time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores, load average "
        f"{load_before[0]:.2f} before and {os.getloadavg()[0]:.2f} after. From the model file's START (as a user "
        "calls it) the steady-state and time-varying forms end on a bound (success False), so their times are not "
        "those of a solve; from the truth all three converge, to their own estimators' optima (the innovation "
        "form's std are the Cramer-Rao bounds of its diagonal weighting).")
    say()
    say("| formulation | from | cold CPU s | warm CPU s | success | status | rounds | iterations | C_mq +/- std |")
    say("|---|---|---|---|---|---|---|---|---|")
    for (form, start), results in runs.items():
        cold = np.array([r["cold"]["cpu"] for r in results])
        warm = np.array([r["warm"]["cpu"] for r in results])
        first = results[0]["cold"]
        say(f"| {form} | {STARTS[start]} | {np.median(cold):.2f} ({cold.min():.2f}-{cold.max():.2f}) | "
            f"{np.median(warm):.2f} ({warm.min():.2f}-{warm.max():.2f}) | {first['success']} | "
            f"{first['status']} | {first['rounds'] or '-'} | {first['iterations']} | "
            f"{first['C_mq']:.3f} +/- {first['C_mq_std']:.3f} |")
    say()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", help="also write the table (Markdown) here")
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(*args.child)))
        return 0
    lines = []

    def say(text=""):
        print(text, flush=True)
        lines.append(text)

    bench(args.repeats, say)
    if args.out:
        sys.path.insert(0, os.path.join(HERE, "..", ".."))
        from casest.data.dataset import atomic_write_text

        atomic_write_text(args.out, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
