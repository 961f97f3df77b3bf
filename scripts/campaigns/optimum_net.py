#!/usr/bin/env python3
"""The global-optimum net: does casest reach the brute-force optimum on 320 generated problems?

    python3 scripts/campaigns/optimum_net.py                      (all 320 against the stored references)
    python3 scripts/campaigns/optimum_net.py --subset             (the 40 of the default test suite)
    python3 scripts/campaigns/optimum_net.py --establish          (recompute the references, ~10 min)
    python3 scripts/campaigns/optimum_net.py --only 17 203 --out results.json
    python3 scripts/campaigns/optimum_net.py --published          (the 81 NIST StRD problems, ~10 s)

The problems (:mod:`nets.optimum_net`): sums of exponentials, Gaussian peaks, rational
and trigonometric terms with 1-4 nonlinear parameters, three noise levels, nominal values at
the box centre or a corner. Each is estimated with ``casest.estimate`` at its defaults and its
concentrated ML cost compared with the lowest one of ``--starts`` bounded SciPy trf runs from
the priors (:func:`nets.references.brute_force`), stored in
``scripts/campaigns/optimum_net_reference.json``. A problem counts as at the global optimum when its gap
is below 1e-6 (log-likelihood units) or 1e-9 relative. A problem whose cost has no minimum in
its box (two terms merging, their amplitudes growing without bound) counts as answered when
casest's estimate carries the merged limit (``Estimate.merged_limit``: a term and its
derivative term) and that limit's cost is at or below the reference. ``--establish`` writes the references
as it goes and resumes where an interrupted run stopped.

``--published`` runs the published part instead (:mod:`nets.published_net`): the 27 NIST
StRD problems from NIST's two starts and from the protocol box's midpoint, against the optimum
their certified residual sum of squares gives.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
import warnings

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402
from nets.optimum_net import NET_SIZE, STRATIFIED, net_problem  # noqa: E402
from nets.published_net import published_names, published_problem  # noqa: E402
from nets.references import at_global_optimum, brute_force, concentrated_cost  # noqa: E402
from casest.data import atomic_write_text  # noqa: E402

REFERENCE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "optimum_net_reference.json")


def establish(indices, n_starts: int) -> None:
    stored = json.load(open(REFERENCE)) if os.path.exists(REFERENCE) else {}
    for done, k in enumerate(indices):
        problem = net_problem(k)
        if problem.name in stored and stored[problem.name]["starts"] >= n_starts:
            continue
        t = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cost, theta = brute_force(problem.model, problem.data, n_starts, seed=k)
        truth_cost = concentrated_cost(problem.model, problem.data, problem.model.vector(problem.truth))
        stored[problem.name] = {"J": cost, "theta": dict(zip(problem.model.parameter_names, theta.tolist())),
                                "J_truth": truth_cost, "starts": n_starts}
        print(f"{problem.name:<26} J* = {cost:.12g}  ({time.perf_counter() - t:.1f} s)", flush=True)
        if done % 10 == 9:
            atomic_write_text(REFERENCE, json.dumps(stored, indent=1, sort_keys=True) + "\n")
    atomic_write_text(REFERENCE, json.dumps(stored, indent=1, sort_keys=True) + "\n")


def _row(name: str, model, data, J_star: float) -> dict:
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = casest.estimate(model, data)
    seconds = time.perf_counter() - t
    J = concentrated_cost(model, data, est.theta)
    ok = at_global_optimum(J, J_star)
    # no attained minimum: casest's merged limit (a term and its derivative) at or below the reference
    limit = est.merged_limit
    J_limit = None if limit is None else concentrated_cost(limit.limit_model(model), data, limit.theta)
    at_limit = not ok and J_limit is not None and at_global_optimum(J_limit, J_star)
    flag = "" if ok else ("   <- no attained minimum: the merged limit" if at_limit else "   <- not global")
    print(f"{name:<26} {J_star:>14.8g} {J:>14.8g} {J - J_star:>9.2g} {str(est.success):>7} "
          f"{len(est.starts):>6} {seconds:>6.2f}{flag}", flush=True)
    return {"problem": name, "J_star": J_star, "J": J, "gap": J - J_star, "global": ok, "merged_limit": at_limit,
            "J_limit": J_limit, "success": bool(est.success), "starts": len(est.starts), "seconds": seconds,
            "trust": est.conclusion()[0].value}


def run(problems) -> list[dict]:
    """``problems``: (name, model, data, J_star) in turn; one row each, and the rate printed."""
    head = f"{'problem':<26} {'global J*':>14} {'casest J':>14} {'gap':>9} {'success':>7} {'starts':>6} {'s':>6}"
    print(head)
    print("-" * len(head))
    rows = [_row(*problem) for problem in problems]
    print("-" * len(head))
    lost = [r["problem"] for r in rows if not (r["global"] or r["merged_limit"])]
    limits = sum(r["merged_limit"] for r in rows)
    print(f"optimum net: {sum(r['global'] for r in rows)}/{len(rows)} at the global optimum, {limits} with no attained "
          f"minimum (casest's merged limit at or below the reference, said in its conclusion)"
          + (f"; lost: {', '.join(lost)}" if lost else "; none lost"))
    print(f"seconds: median {statistics.median(r['seconds'] for r in rows):.2f}, "
          f"total {sum(r['seconds'] for r in rows):.1f}")
    return rows


def generated(indices):
    reference = json.load(open(REFERENCE))
    for k in indices:
        problem = net_problem(k)
        yield problem.name, problem.model, problem.data, reference[problem.name]["J"]


def published():
    for name in published_names():
        problem = published_problem(name)
        yield name, problem.model, problem.data, problem.J_star


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--establish", action="store_true", help="compute the brute-force references")
    parser.add_argument("--starts", type=int, default=200, help="brute-force starts per problem (--establish)")
    parser.add_argument("--subset", action="store_true", help="only the stratified 40 of the test suite")
    parser.add_argument("--only", nargs="*", type=int, default=[], help="only these problem numbers")
    parser.add_argument("--published", action="store_true", help="the 81 published NIST StRD problems instead")
    parser.add_argument("--out", help="write the rows as JSON (atomically)")
    args = parser.parse_args(argv)
    indices = args.only or (list(STRATIFIED) if args.subset else list(range(NET_SIZE)))
    if args.establish:
        establish(indices, args.starts)
        return 0
    rows = run(published() if args.published else generated(indices))
    if args.out:
        atomic_write_text(args.out, json.dumps(rows, indent=1) + "\n")
    return 0 if all(r["global"] or r["merged_limit"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
