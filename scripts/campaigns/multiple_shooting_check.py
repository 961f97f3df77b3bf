#!/usr/bin/env python3
"""Multiple shooting on the bundled unstable aircraft: every run at the global optimum with success,
or failed with a note that says why; never success at another minimum.

    python3 scripts/campaigns/multiple_shooting_check.py [--seeds 10 11 ...] [--intervals 5 10 25 50]
                                                         [--workers 2] [--out out/multiple_shooting]

For each seed the record of ``models/unstable.py`` (a statically unstable short period flown with a
controller, 601 samples) is estimated by ``casest.estimate`` with
``SolverSettings(shooting="multiple", shooting_interval=K)`` for each K, from the nominal values
(the whole pipeline: stage 1 and its starts) and from the model file's ``START``. The reference
optimum of each record is independent of multiple shooting: artificial stabilisation with the
textbook's gain 1.3 I (``casest.artificially_stabilised``), then single-shooting output error of
the plain model from that estimate. A run is *global* where its output-error cost is the
reference's to 1e-6 relative and its estimates are the reference's to 1e-3 of their std.
Each run is written to its own JSON file (atomically); a run on disk is not repeated, so an
interrupted campaign resumes. The exit status is 1 when any run reports success away from the
global optimum.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))
MODEL_FILE = os.path.join(HERE, "..", "..", "models", "unstable.py")
#: the stabilising gain of the textbook's unstable-aircraft case (states alpha, q fed back from their measurements)
STABILISING_GAIN = np.diag([1.3, 1.3])


def reference(seed: int, out: str) -> dict:
    """The record's optimum by artificial stabilisation, polished by single shooting on the plain model."""
    import casest
    from casest.data.files import atomic_write_text

    path = os.path.join(out, f"reference_{seed:05d}.json")
    if os.path.exists(path):
        return json.load(open(path))
    mf = casest.load_model_file(MODEL_FILE)
    model, data = mf.model(), mf.simulate(seed)
    stabilised = casest.artificially_stabilised(model, STABILISING_GAIN)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        first = casest.estimate(stabilised, casest.stabilised_dataset(stabilised, data), start=mf.START, mode="full")
        polished = casest.estimate(model, data, start=dict(zip(model.parameter_names, first.theta)), mode="full")
    record = {"seed": seed, "success": bool(polished.success), "cost": float(polished.cost),
              "theta": polished.theta.tolist(), "std": [float(s) for s in polished.std]}
    atomic_write_text(path, json.dumps(record))
    return record


def one_run(job: tuple) -> str:
    """One (seed, interval, start) estimate, saved with its cost, status and notes' codes."""
    import casest
    from casest.data.files import atomic_write_text

    seed, interval, start_name, out = job
    path = os.path.join(out, f"run_{seed:05d}_{interval:03d}_{start_name}.json")
    if os.path.exists(path):
        return path
    mf = casest.load_model_file(MODEL_FILE)
    model, data = mf.model(), mf.simulate(seed)
    settings = casest.SolverSettings(shooting="multiple", shooting_interval=interval)
    t0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        est = casest.estimate(model, data, start=None if start_name == "nominal" else mf.START,
                              solver_settings=settings)
    record = {"seed": seed, "interval": interval, "start": start_name, "cpu_seconds": time.process_time() - t0,
              "success": bool(est.success), "status": est.status, "cost": float(est.cost),
              "theta": est.theta.tolist(), "notes": [str(n) for n in est.notes],
              "note_codes": [n.code.value for n in est.notes]}
    atomic_write_text(path, json.dumps(record))
    return path


def classify(run: dict, ref: dict) -> str:
    """``"global"``, ``"failed"`` (success False, whatever the point) or ``"WRONG"`` (success elsewhere)."""
    if not run["success"]:
        return "failed"
    std = np.asarray(ref["std"], dtype=float)
    std = np.where(np.isfinite(std) & (std > 0), std, 1.0)
    same_cost = abs(run["cost"] - ref["cost"]) <= 1e-6 * abs(ref["cost"])
    same_point = np.all(np.abs(np.asarray(run["theta"]) - np.asarray(ref["theta"])) <= 1e-3 * std)
    return "global" if same_cost and same_point else "WRONG"


def summarise(out: str, seeds: list, intervals: list) -> tuple[list[str], int]:
    """The table (one row per interval and start) and the count of runs reported at a wrong optimum."""
    refs = {s: json.load(open(os.path.join(out, f"reference_{s:05d}.json"))) for s in seeds}
    lines = [f"models/unstable.py, seeds {seeds}; reference: stabilised (gain 1.3 I) then single shooting; "
             f"every reference converged: {all(r['success'] for r in refs.values())}", "",
             "| samples per interval | start | runs | global, success | failed (note codes) | success elsewhere | "
             "median CPU s |", "|---|---|---|---|---|---|---|"]
    wrong = 0
    for interval in intervals:
        for start in ("nominal", "START"):
            runs = [json.load(open(os.path.join(out, f"run_{s:05d}_{interval:03d}_{start}.json"))) for s in seeds]
            kinds = [classify(r, refs[r["seed"]]) for r in runs]
            failed_codes = sorted({c for r, k in zip(runs, kinds) if k == "failed" for c in r["note_codes"]})
            wrong += kinds.count("WRONG")
            lines.append(f"| {interval} | {start} | {len(runs)} | {kinds.count('global')} | {kinds.count('failed')}"
                         f"{' (' + ', '.join(failed_codes) + ')' if failed_codes else ''} | {kinds.count('WRONG')} | "
                         f"{np.median([r['cpu_seconds'] for r in runs]):.1f} |")
    return lines, wrong


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(10, 18)), help="records (seeds)")
    parser.add_argument("--intervals", type=int, nargs="+", default=[5, 10, 25, 50], help="samples per interval")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    parser.add_argument("--out", default=os.path.join(HERE, "..", "..", "out", "multiple_shooting"),
                        help="folder of the per-run JSON files (a rerun resumes)")
    args = parser.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    t0 = time.perf_counter()
    jobs = [(s, k, start, args.out) for s in args.seeds for k in args.intervals for start in ("nominal", "START")]
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        list(pool.map(reference, args.seeds, [args.out] * len(args.seeds)))
        list(pool.map(one_run, jobs))
    lines, wrong = summarise(args.out, args.seeds, args.intervals)
    print("\n".join(lines))
    print(f"\nwall time {time.perf_counter() - t0:.0f} s")
    return 1 if wrong else 0


if __name__ == "__main__":
    sys.exit(main())
