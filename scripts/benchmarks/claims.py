#!/usr/bin/env python3
"""The benchmark claims: each measured in fresh processes, stated as a median with its range,
and checked again by a second run.

    python3 scripts/benchmarks/claims.py record [--runs 9] [--only NAME ...] [--conditions 0 1 2] [--append]
    python3 scripts/benchmarks/claims.py check  [--runs 7] [--only NAME ...] [--beside N]
    python3 scripts/benchmarks/claims.py measure NAME [--run K]   (one run, JSON on stdout)

A *measurement* runs its contenders interleaved with the order alternated, each the fastest of a
few repetitions in CPU seconds, and returns figures (ratios of CPU times, counts, CPU seconds,
MiB). Every run of a measurement is a fresh process; the run's index ``K`` alternates the order
of contenders that are processes of their own. ``--beside N`` runs the measurements beside N
CPU-bound processes (``busy.py``): a claim stated as a ratio of CPU times should hold there too. ``record`` runs each measurement ``--runs``
times, run K beside ``conditions[K % len(conditions)]`` CPU-bound processes (default 0, 1 and 2
in turn: the stated range is what an idle and a busy machine give, not an idle one only), and
stores, per claim, the median and the range of those runs, each condition's median and range,
the date, the machine's CPU, its load (the 1-minute load average before and after each run) and
the command, in ``scripts/benchmarks/claims.json``, and writes the table of
``docs/benchmark-claims.md``.
``--append`` adds the runs to those stored the same day (a machine whose times drift over the
day needs its range from more than one session). ``check`` runs each measurement again ``--runs`` times and fails (exit status 1) when a
claim's median today falls outside its stored range; it prints both. ``bench.py --check`` is
``check``. A stated figure needs at least seven runs.

What each measurement compares, and why it is fair to the peer, is in its docstring.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.abspath(os.path.join(HERE, "..", ".."))
STORE = os.path.join(HERE, "claims.json")
PAGE = os.path.join(REPO, "docs", "benchmark-claims.md")
sys.path.insert(0, HERE)
sys.path.insert(0, REPO)

from claim_measurements import MEASUREMENTS, PREPARE  # noqa: E402

#: claim -> (measurement, figure, what the figure says)
CLAIMS = {
    "stage2_over_lmfit": ("stage2_nist", "over_lmfit",
                          "warm stage 2 alone / lmfit leastsq (exact Jacobian), median over the 24 NIST rows"),
    "stage2_over_scipy": ("stage2_nist", "over_scipy",
                          "warm stage 2 alone / SciPy least_squares trf (exact Jacobian), median over the 24 NIST rows"),
    "stage2_rows_slower_than_scipy": ("stage2_nist", "slower_than_scipy",
                                      "NIST rows where warm stage 2 alone is slower than SciPy trf (of 24)"),
    "pipeline_over_scipy": ("pipeline_nist", "over_scipy",
                            "warm pipeline (stage 1, every start, covariance) / one SciPy trf fit, median over the 24 "
                            "NIST rows"),
    "ekf_over_numba_1e2": ("ekf", "over_numba_100", "EKF compiled pass, warm / numba loop EKF, N = 1e2"),
    "ekf_over_numba_1e3": ("ekf", "over_numba_1000", "EKF compiled pass, warm / numba loop EKF, N = 1e3"),
    "ekf_over_numba_1e4": ("ekf", "over_numba_10000", "EKF compiled pass, warm / numba loop EKF, N = 1e4"),
    "ekf_over_numba_1e5": ("ekf", "over_numba_100000", "EKF compiled pass, warm / numba loop EKF, N = 1e5"),
    "ekf_over_numba_1e6": ("ekf", "over_numba_1000000", "EKF compiled pass, warm / numba loop EKF, N = 1e6"),
    "ekf_out_over_numba_1e6": ("ekf", "out_over_numba_1000000",
                               "the same, N = 1e6, casest's pass written into its previous pass's arrays (out=)"),
    "stage1_numpy_over_casest_1e3": ("stage1", "numpy_over_casest_1000_5000",
                                     "stage-1 sweep, NumPy peer / casest, one thread each, N = 1e3, K = 5000 "
                                     "(above 1: casest faster)"),
    "stage1_numpy_over_casest_small": ("stage1", "numpy_over_casest_100_100",
                                       "the same, N = 100, K = 100 (below the compile threshold; the compile cache "
                                       "holds the Gram sums)"),
    "ap2_example_over_reference": ("ap2_example", "over_reference",
                                   "the AP2 worked example (warm compile cache, --no-figures), CPU seconds of its "
                                   "process / those of the reference workload (reference_workload.py: SciPy fits of "
                                   "the NIST rows; no peer runs the whole example)"),
    "output_error_jax_over_default_warm": ("output_error_jax", "jax_over_default_warm",
                                           "aircraft output error (38 parameters, N = 3001), warm: JAX + SciPy's fit / "
                                           "casest's whole Gauss-Newton estimate (exact-Hessian covariance)"),
    "output_error_jax_over_gn_cov_warm": ("output_error_jax", "jax_over_gn_cov_warm",
                                          "the same, casest with the Gauss-Newton covariance, warm"),
    "output_error_jax_over_gn_cov_cold": ("output_error_jax", "jax_over_gn_cov_cold",
                                          "the same, cold (casest: empty compile cache; JAX: first jit)"),
    "stage1_memory_first_above_record_1e6": ("stage1_memory", "first_above_record_mib_1e6",
                                             "stage-1 sweep's peak RSS above the loaded record, MiB, a fresh process's "
                                             "first sweep, Pitot N = 1e6, 500 candidates"),
    "stage1_memory_first_over_record_1e6": ("stage1_memory", "first_over_record_1e6",
                                            "the same sweep's peak above the process before the record / the "
                                            "record's size (122 MiB)"),
    "cold_first_estimate_over_scipy_first_fit": ("cold_start", "first_over_scipy_first",
                                                 "Pitot default, fresh processes, compile cache filled: casest's first "
                                                 "estimate (stage 1 included) / SciPy's first least_squares fit (BLAS on "
                                                 "one thread), CPU seconds"),
    "profile_lmfit_over_casest": ("profile_lmfit", "lmfit_over_casest",
                                  "profile intervals of every parameter, lmfit conf_interval (NumPy residual) / casest, "
                                  "median over 5 problems (above 1: casest faster)"),
    "profile_problems_lmfit_faster": ("profile_lmfit", "lmfit_faster",
                                      "of those 5 problems, where lmfit's conf_interval is faster"),
    "import_over_dependencies": ("import_cost", "import_over_dependencies",
                                 "`import casest` in a fresh process / `import numpy, casadi` (what it loads) in "
                                 "another, CPU seconds, the fastest of 9 each"),
}


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def run_once(name: str, index: int) -> dict:
    """Run ``index`` of a measurement in a fresh process, with the load average around it."""
    before = os.getloadavg()[0]
    done = subprocess.run([sys.executable, os.path.abspath(__file__), "measure", name, "--run", str(index)],
                          capture_output=True, text=True, cwd=REPO)
    after = os.getloadavg()[0]
    if done.returncode != 0:
        raise RuntimeError(f"measurement {name} failed:\n{done.stderr[-2000:]}")
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    return {"figures": figures, "load": max(before, after)}


def measure_all(names, runs: int, conditions=(0,)) -> dict:
    """measurement -> list of runs (each {"figures", "load", "beside"}), run K beside
    ``conditions[K % len(conditions)]`` CPU-bound processes."""
    from busy import cpu_bound_processes

    out = {}
    for name in names:
        out[name] = []
        if name in PREPARE:
            PREPARE[name]()
        for k in range(runs):
            beside = int(conditions[k % len(conditions)])
            with cpu_bound_processes(beside):
                out[name].append({**run_once(name, k), "beside": beside})
            print(f"  {name} run {k + 1}/{runs} (beside {beside}): "
                  + ", ".join(f"{f} {v:.4g}" for f, v in out[name][-1]["figures"].items()), flush=True)
    return out


def summarise(runs: list, figure: str) -> dict:
    """Median, range, count, largest load and values of ``figure`` over ``runs``; with runs at more
    than one condition, the same per condition (``by_condition``, keyed by the busy processes)."""
    values = [r["figures"][figure] for r in runs]
    out = {"median": float(np.median(values)), "min": float(min(values)), "max": float(max(values)),
           "runs": len(values), "load": float(max(r["load"] for r in runs)), "values": values}
    conditions = sorted({r.get("beside", 0) for r in runs})
    if len(conditions) > 1:
        out["by_condition"] = {str(b): summarise([r for r in runs if r.get("beside", 0) == b], figure)
                               for b in conditions}
    return out


def selected(only) -> tuple[dict, list]:
    claims = {k: v for k, v in CLAIMS.items() if not only or k in only or v[0] in only}
    if only and not claims:
        raise SystemExit(f"no claim or measurement named {only}: choose from {sorted(CLAIMS)}")
    return claims, sorted({m for m, _, _ in claims.values()})


def record(only, runs: int, append: bool = False, conditions=(0, 1, 2)) -> int:
    """Measure and store the claims, run K beside ``conditions[K % len(conditions)]`` CPU-bound
    processes; with ``append``, today's runs join those stored today (the range then spans every
    session of the day, as a drifting machine needs)."""
    from casest.data import atomic_write_text

    claims, names = selected(only)
    measured = measure_all(names, runs, conditions)
    stored = json.load(open(STORE)) if os.path.exists(STORE) else {}
    stored = {k: v for k, v in stored.items() if k in CLAIMS}  # claims no longer made
    today = datetime.date.today().isoformat()
    for claim, (name, figure, text) in claims.items():
        runs_of = measured[name]
        earlier = stored.get(claim, {})
        if append and earlier.get("date") == today:
            runs_of = [{"figures": {figure: v}, "load": earlier["load"], "beside": b}
                       for v, b in zip(earlier["values"], earlier.get("beside", [0] * len(earlier["values"])))] + runs_of
        command = (f"python3 scripts/benchmarks/claims.py record --runs {runs} --only {name}"
                   + (f" --conditions {' '.join(map(str, conditions))}" if tuple(conditions) != (0, 1, 2) else "")
                   + (" --append" if append else ""))
        stored[claim] = {"text": text, "measurement": name, "figure": figure, "date": today, "cpu": cpu_model(),
                         "cores": os.cpu_count(), "command": command, "beside": [r.get("beside", 0) for r in runs_of],
                         **summarise(runs_of, figure)}
    atomic_write_text(STORE, json.dumps(stored, indent=1, sort_keys=True) + "\n")
    atomic_write_text(PAGE, page(stored))
    print(f"wrote {STORE} and {PAGE}")
    return 0


def page(stored: dict) -> str:
    """The claims page: every stored claim's median and range, and those of each load condition."""
    lines = ["# Benchmark claims", "",
             "Every figure casest states about its speed (a ratio of CPU times: against a peer, or where no "
             "peer does the same work, against its dependencies or a fixed reference workload) and its memory, "
             "as the median and the range of `runs` fresh-process runs of its measurement (`scripts/benchmarks/claim_measurements.py`: contenders "
             "interleaved, the order alternated, each the fastest of a few repetitions in CPU seconds). The runs "
             "take turns at three conditions: on an otherwise idle machine, beside one and beside two CPU-bound "
             "processes (`scripts/benchmarks/busy.py`; this machine has two cores), so the range is what a user "
             "sees on an idle or a busy machine; the column by condition gives each condition's median and range. "
             "`python3 scripts/benchmarks/bench.py --check [--beside N]` measures each again (beside N busy "
             "processes) and fails when today's median leaves the stated range. Load: the largest 1-minute load "
             "average seen around the runs (it lags: the busy processes change from run to run).", "",
             "| claim | median | range | runs | date | load | CPU (cores) | by condition | command |",
             "|---|---|---|---|---|---|---|---|---|"]
    for claim in CLAIMS:
        if claim not in stored:
            continue
        c = stored[claim]
        split = "; ".join(f"{'idle' if int(k) == 0 else f'beside {k}'}: {b['median']:.3g} ({b['min']:.3g}-{b['max']:.3g})"
                          for k, b in sorted(c.get("by_condition", {}).items(), key=lambda kv: int(kv[0]))) or "one condition"
        lines.append(f"| {c['text']} | {c['median']:.3g} | {c['min']:.3g}-{c['max']:.3g} | {c['runs']} | {c['date']} | "
                     f"{c['load']:.2f} | {c['cpu']} ({c['cores']}) | {split} | `{c['command']}` |")
    return "\n".join(lines) + "\n"


def check(only, runs: int, beside: int = 0) -> int:
    """Measure the stated claims again, beside ``beside`` CPU-bound processes; 1 when a median
    leaves its stated range."""
    stored = json.load(open(STORE))
    claims, names = selected(only)
    claims = {k: v for k, v in claims.items() if k in stored}
    measured = measure_all(sorted({m for m, _, _ in claims.values()}), runs, (beside,))
    failed = 0
    print(f"\n{'claim':<32} {'stated median':>13} {'stated range':>21} {'today median':>13} {'today range':>21}  result")
    for claim, (name, figure, _) in claims.items():
        c, today = stored[claim], summarise(measured[name], figure)
        inside = c["min"] <= today["median"] <= c["max"]
        failed += not inside
        print(f"{claim:<32} {c['median']:>13.4g} {c['min']:>10.4g}-{c['max']:<10.4g} {today['median']:>13.4g} "
              f"{today['min']:>10.4g}-{today['max']:<10.4g}  {'ok' if inside else 'OUTSIDE'}  (load {today['load']:.2f})")
    print(f"\n{len(claims) - failed} of {len(claims)} claims reproduced ({datetime.datetime.now().isoformat(timespec='minutes')}, "
          f"{cpu_model()}, {os.cpu_count()} cores, beside {beside} CPU-bound processes, {runs} runs)")
    return 1 if failed else 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("action", choices=("record", "check", "measure"))
    parser.add_argument("name", nargs="?", help="measure: the measurement")
    parser.add_argument("--runs", type=int, default=None, help="runs per measurement (default: record 9, check 7)")
    parser.add_argument("--conditions", type=int, nargs="+", default=[0, 1, 2],
                        help="record: CPU-bound processes beside each run, in turn (default 0 1 2)")
    parser.add_argument("--run", type=int, default=0, help="measure: the run's index (alternates process order)")
    parser.add_argument("--beside", type=int, default=0, help="check: beside this many CPU-bound processes")
    parser.add_argument("--only", nargs="*", default=None, help="claims or measurements")
    parser.add_argument("--append", action="store_true", help="record: add the runs to those stored today")
    args = parser.parse_args(argv)
    if args.action == "measure":
        t = time.perf_counter()
        figures = MEASUREMENTS[args.name](args.run)
        print(f"# {args.name}: {time.perf_counter() - t:.1f} s", file=sys.stderr)
        print(json.dumps(figures))
        return 0
    runs = args.runs or (9 if args.action == "record" else 7)
    if runs < 7:
        print(f"note: {runs} runs; a stated figure needs at least 7", file=sys.stderr)
    if args.action == "record":
        return record(args.only, runs, args.append, tuple(args.conditions))
    return check(args.only, runs, args.beside)


if __name__ == "__main__":
    sys.exit(main())
