#!/usr/bin/env python3
"""casest's global pipeline against a global peer: SciPy trf from Sobol starts, stopped when the best
cost has not improved for k starts.

    python3 scripts/benchmarks/global_peer.py [--max-starts 64] [--ks 1 2 3 4 6 8 12 16] [--out FILE.md]
    python3 scripts/benchmarks/global_peer.py --net-only            (choose k on the net, no NIST timings)
    python3 scripts/benchmarks/global_peer.py --choose-on nist      (choose k on the NIST rows, then time them)

The peer is written as a competent user would, with the same information as casest: the box
(each boxed parameter's starts are scrambled Sobol points mapped through its sampling prior, the
distribution casest's sweep draws from; parameters without a box start at their nominal value),
the exact Jacobian (a CasADi SX function of the parameters with the data inside, built once and
timed warm; the NIST rows use the hand-written NumPy residual and Jacobian of
``scripts/benchmarks/stage2_peers.py``), ``least_squares(method='trf', x_scale='jac')`` with
tolerances 1e-12, and the criterion (single-output problems: least squares is the ML cost).
A start improves the best when its cost is lower by more than 1e-9 relative; the peer stops when
k consecutive starts have not improved it.

1. **Choosing k on the global-optimum net** (``nets.optimum_net``, the 320 problems with
   their brute-force references in ``scripts/campaigns/optimum_net_reference.json``): each
   problem's first ``--max-starts`` fits are run once and the stopping rule is replayed on that
   sequence for every k; a problem counts as at the optimum as the net's campaign counts it
   (``nets.references.at_global_optimum`` on the concentrated cost). casest's own rate
   and time come from ``casest.estimate`` at its defaults (warm: the second call). The chosen k
   is the smallest whose rate reaches casest's. With ``--choose-on nist`` k is chosen the same way
   on the NIST rows themselves (NIST's start first, then the Sobol starts): the rows the peer is
   then timed on.
2. **The 24 NIST rows** (``data/nist_strd``, both starts) and the net: casest's warm pipeline
   against the peer with that k (warm: functions built, the same call again), each the fastest
   of ``--repeats``; and, where stage 1 says one solve suffices ("unique"), one SciPy trf fit
   from casest's stage-2 start. Whether each found the certified (NIST) or reference (net) optimum.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import sys
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "campaigns"))  # the nets (package ``nets``)

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402

import casest  # noqa: E402
from casest.apps.nist import read_nist  # noqa: E402
from nets.optimum_net import NET_SIZE, net_problem  # noqa: E402
from nets.references import at_global_optimum, concentrated_cost  # noqa: E402
from casest.data.files import atomic_write_text  # noqa: E402

REFERENCE = os.path.join(HERE, "..", "campaigns", "optimum_net_reference.json")


def casadi_problem(model, data):
    """The residual ``f(x_k, theta) - z_k`` and its Jacobian as NumPy callables (a CasADi SX
    function of theta with the data inside, built once)."""
    theta = ca.SX.sym("theta", model.n_parameters)
    predicted = ca.vec(model.function.map(data.n_samples)(data.signals.T, theta).T)  # sample-major rows
    r = predicted - ca.DM(data.outputs.reshape(-1, order="F"))
    fun = ca.Function("peer_rj", [theta], [r, ca.jacobian(r, theta)])

    def residual(th):
        return np.asarray(fun(th)[0]).reshape(-1)

    def jacobian(th):
        return np.asarray(fun(th)[1])

    return residual, jacobian


def sobol_starts(model, n: int, seed: int) -> np.ndarray:
    """``n`` starts: scrambled Sobol points through each boxed parameter's sampling prior; the
    nominal value for parameters without a box; strictly inside the bounds (trf needs it)."""
    from scipy.stats import qmc

    lb, ub = model.lower_bounds, model.upper_bounds
    boxed = [i for i, p in enumerate(model.parameters) if np.isfinite(p.lb) and np.isfinite(p.ub)]
    starts = np.tile(model.nominal.astype(float), (n, 1))
    if boxed:
        u = qmc.Sobol(len(boxed), scramble=True, seed=seed).random(n)
        u = np.clip(u, 1e-12, 1 - 1e-12)
        for j, i in enumerate(boxed):
            p = model.parameters[i]
            starts[:, i] = p.sampling_prior.ppf(u[:, j], p.lb, p.ub)
    span = np.where(np.isfinite(ub - lb), ub - lb, 1.0)
    return np.clip(starts, lb + 1e-9 * span, ub - 1e-9 * span)


def fit(residual, jacobian, model, start) -> tuple[np.ndarray, float, float]:
    """One bounded trf fit: (theta, cost 1/2 r'r, seconds)."""
    from scipy.optimize import least_squares

    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            out = least_squares(residual, start, jac=jacobian, bounds=(model.lower_bounds, model.upper_bounds),
                                method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=2000)
        except (ValueError, np.linalg.LinAlgError):  # a start where the model overflows: no fit
            return start, np.inf, time.perf_counter() - t
    cost = float(out.cost)
    return out.x, (cost if np.isfinite(cost) else np.inf), time.perf_counter() - t


def run_sequence(residual, jacobian, model, starts) -> list[tuple]:
    """Every start's fit in turn: (theta, cost, seconds) each."""
    return [fit(residual, jacobian, model, s) for s in starts]


def stopped(sequence: list, k: int) -> tuple[np.ndarray, float, int]:
    """The stopping rule replayed on a recorded sequence: (best theta, seconds spent, starts run)
    when k consecutive starts have not lowered the best cost by more than 1e-9 relative."""
    best_cost, best_theta, since, spent = np.inf, None, 0, 0.0
    for n, (theta, cost, seconds) in enumerate(sequence, start=1):
        spent += seconds
        if best_theta is None or cost < best_cost - 1e-9 * abs(best_cost):
            best_cost, best_theta, since = cost, theta, 0
        else:
            since += 1
        if since >= k:
            return best_theta, spent, n
    return best_theta, spent, len(sequence)


def warm_estimate(model, data, repeats: int):
    """casest.estimate at its defaults: the fastest of ``repeats`` calls after a first one
    (``nist_breakdown.fastest_estimate``), warnings silenced."""
    from nist_breakdown import fastest_estimate

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fastest_estimate(model, data, repeats)


def choose_k(ks, max_starts: int, out: list) -> int:
    """Rates on the net per k, and casest's; prints the table; the smallest k reaching casest's rate."""
    reference = json.load(open(REFERENCE))
    hits = {k: 0 for k in ks}
    seconds = {k: [] for k in ks}
    ours, our_seconds = 0, []
    for index in range(NET_SIZE):
        problem = net_problem(index)
        model, data, J_star = problem.model, problem.data, reference[problem.name]["J"]
        residual, jacobian = casadi_problem(model, data)
        sequence = run_sequence(residual, jacobian, model, sobol_starts(model, max_starts, seed=index))
        for k in ks:
            theta, spent, _ = stopped(sequence, k)
            hits[k] += at_global_optimum(concentrated_cost(model, data, theta), J_star)
            seconds[k].append(spent)
        wall, est = warm_estimate(model, data, 1)
        ours += at_global_optimum(concentrated_cost(model, data, est.theta), J_star)
        our_seconds.append(wall)
        if index % 40 == 39:
            print(f"  net: {index + 1}/{NET_SIZE} problems", file=sys.stderr, flush=True)
    return _k_table(out, f"Global-optimum net, {NET_SIZE} problems: the share at the brute-force optimum and the "
                    "median warm time per problem.", "at the optimum", f"{1e3 * np.median(our_seconds):.1f}",
                    "Sobol starts", hits, seconds, ks, NET_SIZE, ours, "")


def _k_table(out: list, title: str, column: str, casest_ms: str, starts_words: str, hits: dict, seconds: dict, ks,
             total: int, ours: int, where: str) -> int:
    """The table of rates and median times per k (casest's first), and the chosen k: the smallest
    whose rate reaches casest's (the largest when none does)."""
    out += [title, "", f"| method | {column} | median ms |", "|---|---|---|",
            f"| casest.estimate (defaults) | {ours}/{total} | {casest_ms} |"]
    for k in ks:
        out.append(f"| SciPy trf, {starts_words}, stop after k = {k} without improvement | {hits[k]}/{total} | "
                   f"{1e3 * np.median(seconds[k]):.1f} |")
    out.append("")
    reaching = [k for k in ks if hits[k] >= ours]
    chosen = reaching[0] if reaching else ks[-1]
    out.append(f"Chosen k = {chosen}: " + (f"the smallest whose rate{where} reaches casest's." if reaching else
                                           f"no k up to {ks[-1]} reaches casest's rate; the largest is used."))
    out.append("")
    return chosen


def _nist_problems():
    """The 24 NIST rows: (name, problem) for each file of ``data/nist_strd`` from both starts."""
    for path in sorted(glob.glob(os.path.join(HERE, "..", "..", "data", "nist_strd", "*.dat"))):
        for start in (1, 2):
            yield f"{os.path.basename(path)[:-4]}/{start}", read_nist(path, start=start)


def _peer_starts(model, max_starts: int) -> np.ndarray:
    """The peer's starts on a NIST row: NIST's start first, then scrambled Sobol points (seed 0)."""
    starts = sobol_starts(model, max_starts, seed=0)
    starts[0] = np.clip(model.nominal, model.lower_bounds, model.upper_bounds)
    return starts


def choose_k_on_nist(ks, max_starts: int, out: list) -> int:
    """Rates on the 24 NIST rows per k (the certified optimum reached, 1e-6 relative in the sum of
    squares), and casest's; prints the table; the smallest k reaching casest's rate."""
    from bench_stage2 import residual_functions

    hits = {k: 0 for k in ks}
    seconds = {k: [] for k in ks}
    ours = 0
    rows = 0
    for name, problem in _nist_problems():
        model, data = problem.model, problem.data
        certified = 0.5 * problem.certified_rss
        residual, jacobian = residual_functions(model, data, model.nominal)
        sequence = run_sequence(residual, jacobian, model, _peer_starts(model, max_starts))
        for k in ks:
            theta, spent, _ = stopped(sequence, k)
            hits[k] += 0.5 * float(np.sum(residual(theta) ** 2)) <= certified * (1 + 1e-6)
            seconds[k].append(spent)
        _, est = warm_estimate(model, data, 1)
        ours += 0.5 * float(np.sum((data.outputs - model.predict(est.theta, data.signals)) ** 2)) <= certified * (1 + 1e-6)
        rows += 1
        print(f"  choosing k: {name}", file=sys.stderr, flush=True)
    return _k_table(out, f"The 24 NIST rows: the share at the certified optimum per k (the peer's stopping rule "
                    f"chosen on these rows, at most {max_starts} starts, NIST's start first) and the median time per "
                    "row of the recorded sequence.", "at the certified optimum", "-", "NIST start then Sobol starts",
                    hits, seconds, ks, rows, ours, " on these rows")


def nist_rows(k: int, max_starts: int, repeats: int, out: list) -> None:
    """casest's warm pipeline against the peer with ``k`` on the 24 NIST rows."""
    from bench_stage2 import residual_functions, scipy_fit

    out.append(f"NIST StRD rows (both starts), warm, fastest of {repeats}; the peer with k = {k} (at most "
               f"{max_starts} starts); one SciPy fit from casest's stage-2 start where stage 1 says one solve suffices.")
    out.append("")
    out.append("| problem | casest ms | casest optimum | peer ms | peer starts | peer optimum | peer / casest | "
               "stage-1 verdict | one SciPy fit ms | casest / one fit |")
    out.append("|---|---|---|---|---|---|---|---|---|---|")
    ratios, both = [], []
    for name, problem in _nist_problems():
        model, data = problem.model, problem.data
        certified = 0.5 * problem.certified_rss
        wall, est = warm_estimate(model, data, repeats)
        our_cost = 0.5 * float(np.sum((data.outputs - model.predict(est.theta, data.signals)) ** 2))
        our_ok = our_cost <= certified * (1 + 1e-6)
        residual, jacobian = residual_functions(model, data, model.nominal)
        starts = _peer_starts(model, max_starts)
        best = None
        for _ in range(repeats):
            sequence, n_run, spent = [], 0, 0.0
            for s in starts:  # the peer as it runs: stops by itself
                sequence.append(fit(residual, jacobian, model, s))
                theta, spent, n_run = stopped(sequence, k)
                if n_run < len(sequence):
                    break
            if best is None or spent < best[0]:
                best = (spent, theta, n_run)
        peer_s, peer_theta, peer_starts = best
        peer_cost = 0.5 * float(np.sum(residual(peer_theta) ** 2))
        peer_ok = peer_cost <= certified * (1 + 1e-6)
        ratio = peer_s / wall
        ratios.append(ratio)
        if our_ok and peer_ok:
            both.append(ratio)
        verdict = est.landscape.verdict if est.landscape is not None else "-"
        one = "-"
        one_ratio = "-"
        if verdict == "unique" and est.starts:
            t_one = min(scipy_fit(model, data, np.asarray(est.starts[0].theta0, dtype=float), "analytic", False)[1]
                        for _ in range(repeats))
            one, one_ratio = f"{1e3 * t_one:.1f}", f"{wall / t_one:.2f}"
        out.append(f"| {name} | {1e3 * wall:.1f} | {'yes' if our_ok else 'no'} | {1e3 * peer_s:.1f} | {peer_starts} | "
                   f"{'yes' if peer_ok else 'no'} | {ratio:.2f} | {verdict} | {one} | {one_ratio} |")
        print(f"  {name}", file=sys.stderr, flush=True)
    out.append("")
    out.append(f"Median peer / casest: {np.median(ratios):.2f} over {len(ratios)} rows; where both reach the certified "
               f"optimum ({len(both)} rows): median {np.median(both):.2f}, smallest {min(both):.2f} (above 1: casest "
               "is faster).")
    out.append("")


def report(max_starts: int = 32, ks=(1, 2, 3, 4, 6, 8, 12, 16), repeats: int = 3, say=print, k: int | None = None
           ) -> None:
    """Choose k on the net (unless given), then the NIST rows; every line through ``say``."""
    out: list[str] = []
    k = k if k is not None else choose_k(sorted(ks), max_starts, out)
    nist_rows(k, max_starts, repeats, out)
    for line in out:
        say(line)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--max-starts", type=int, default=64, help="Sobol starts recorded per problem")
    parser.add_argument("--ks", type=int, nargs="+", default=[1, 2, 3, 4, 6, 8, 12, 16])
    parser.add_argument("--k", type=int, help="skip the net: use this k")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--net-only", action="store_true", help="choose k on the net only")
    parser.add_argument("--choose-on", choices=("net", "nist"), default="net",
                        help="where the peer's k is chosen: the global-optimum net, or the NIST rows it is timed on")
    parser.add_argument("--out", help="also write the tables (Markdown) here")
    args = parser.parse_args(argv)
    out: list[str] = []
    if args.k is not None:
        k = args.k
    elif args.choose_on == "nist":
        k = choose_k_on_nist(sorted(args.ks), args.max_starts, out)
    else:
        k = choose_k(sorted(args.ks), args.max_starts, out)
    if not args.net_only:
        nist_rows(k, args.max_starts, args.repeats, out)
    text = "\n".join(out) + "\n"
    print(text)
    if args.out:
        atomic_write_text(args.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
