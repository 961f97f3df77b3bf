#!/usr/bin/env python3
"""Monte-Carlo coverage of the +-1.96 std intervals, the likelihood-ratio sets from the sweep and
the profile-likelihood intervals (95 %).

    python3 scripts/campaigns/coverage.py [--runs 200] [--cases scalar1 scalar2 near_bound pitot] [--out coverage.jsonl]

Cases (each run simulated with its own seed, the truth known):

- ``scalar1``: paper scalar example 1 (Eq. 21), N = 100;
- ``scalar2``: paper scalar example 2 (Eq. 31), N = 100;
- ``near_bound``: scalar example 1 with b = 0.02 in its box [0, 0.2] (one std above the lower
  bound), the others as the paper's;
- ``pitot``: the five-hole Pitot calibration (Sec. IV) with Table 5's short windows: stage 1 on
  the stage-1 windows, stage 2 on the stage-2 windows (``--pitot-runs``, default 60).

Per run and parameter: whether the truth lies in ``theta +- 1.96 std`` (the estimate's std),
in the likelihood-ratio set of the swept parameters from the sweep (refined to 1e-6 relative of
the box, ``confidence_sets``), and in the profile-likelihood interval
(``profile_intervals``, all parameters). Rows are appended to ``--out`` (JSON lines, one write
each); a later call with the same file skips the runs already there (resume). The table gives
each rate with its Monte-Carlo standard error ``sqrt(p (1 - p) / n)``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import numpy as np  # noqa: E402

import casest  # noqa: E402
from journal import append, load  # noqa: E402
from casest.two_stage.profile import profile_intervals  # noqa: E402
from casest.two_stage.sweep.confidence import confidence_sets  # noqa: E402

LEVEL, Z = 0.95, 1.959963984540054
CASES = ("scalar1", "scalar2", "near_bound", "pitot")


def case_problem(case: str, seed: int):
    """(problem, truth dict, the sweep's problem) of one run."""
    if case in ("scalar1", "scalar2"):
        module = casest.load_model_file(case)
        model, data = module.model(), module.simulate(seed=seed)
        problem = casest.Problem(model, data)
        return problem, dict(module.TRUTH), problem
    if case == "near_bound":
        module = casest.load_model_file("scalar1")
        model = module.model()
        truth = dict(module.TRUTH, b=0.02)
        eta = np.linspace(1.0, 10.0, 100)
        rng = np.random.default_rng([seed, 17])
        clean = model.predict(model.vector(truth), eta[:, None])[:, 0]
        data = casest.Dataset(model, {"eta": eta, "z": clean + module.NOISE_STD * rng.standard_normal(eta.size)})
        problem = casest.Problem(model, data)
        return problem, truth, problem
    module = casest.load_model_file("pitot5hole")
    model = module.model()
    stage1, stage2 = module.stage_data(module.simulate(seed))
    problem = casest.Problem(model, stage2, stage1_data=stage1)
    return problem, dict(module.TRUTH), casest.Problem(model, stage1)


def one_run(case: str, seed: int) -> dict:
    """The coverage flags of one run (and its time)."""
    t0 = time.perf_counter()
    problem, truth, sweep_problem = case_problem(case, seed)
    model = problem.model
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = casest.estimate(problem)
        theta = np.asarray(est.theta)
        wald = {n: bool(abs(theta[i] - truth[n]) <= Z * est.std[i]) for i, n in enumerate(model.parameter_names)}
        profiles = profile_intervals(problem, est.theta, est.R, est.std, level=LEVEL)
        profile = {n: bool(p.lower <= truth[n] <= p.upper) for n, p in profiles.items()}
        partition = casest.separate(model)
        box = {n: model.parameters[model.parameter_names.index(n)] for n in partition.nonlinear}
        tol = 1e-6 * min(p.ub - p.lb for p in box.values())
        sets = confidence_sets(sweep_problem, level=LEVEL, tol=tol)
        lr = {n: bool(any(a <= truth[n] <= b for a, b in s.intervals)) for n, s in sets.parameters.items()}
        disjoint = {n: len(s.intervals) for n, s in sets.parameters.items()}
    return {"case": case, "seed": seed, "success": bool(est.success), "wald": wald, "profile": profile, "lr_set": lr,
            "lr_pieces": disjoint, "seconds": time.perf_counter() - t0}


def table(rows: list) -> str:
    """Coverage per case and parameter, with Monte-Carlo standard errors."""
    lines = ["| case | parameter | runs | +-1.96 std | likelihood-ratio set (sweep) | profile interval | "
             "LR set in pieces |", "|---|---|---|---|---|---|---|"]
    for case in CASES:
        mine = [r for r in rows if r["case"] == case]
        if not mine:
            continue
        for name in mine[0]["wald"]:
            n = len(mine)
            cells = []
            for kind in ("wald", "lr_set", "profile"):
                flags = [r[kind][name] for r in mine if name in r[kind]]
                if not flags:
                    cells.append("-")
                    continue
                p = float(np.mean(flags))
                cells.append(f"{100 * p:.1f} % +- {100 * np.sqrt(p * (1 - p) / len(flags)):.1f}")
            pieces = [r["lr_pieces"][name] for r in mine if name in r["lr_pieces"]]
            split = f"{sum(k > 1 for k in pieces)}/{len(pieces)}" if pieces else "-"
            lines.append(f"| {case} | {name} | {n} | {cells[0]} | {cells[1]} | {cells[2]} | {split} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--pitot-runs", type=int, default=60)
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--out", default="coverage.jsonl", help="the journal (JSON lines; resumed when it exists)")
    args = parser.parse_args(argv)
    rows = load(args.out)
    done = {(r["case"], r["seed"]) for r in rows}
    for case in args.cases:
        runs = args.pitot_runs if case == "pitot" else args.runs
        for seed in range(runs):
            if (case, seed) in done:
                continue
            row = one_run(case, seed)
            append(args.out, row)
            rows.append(row)
        mine = [r for r in rows if r["case"] == case]
        print(f"{case}: {len(mine)} runs, {sum(r['seconds'] for r in mine):.0f} s", file=sys.stderr, flush=True)
    print(table([r for r in rows if r["case"] in args.cases]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
