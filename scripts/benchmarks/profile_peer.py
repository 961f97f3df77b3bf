#!/usr/bin/env python3
"""Profile-likelihood intervals: casest's ``profile_intervals`` against lmfit's ``conf_interval``.

    python3 scripts/benchmarks/profile_peer.py [--repeats 3]

For each problem (paper scalar examples 1 and 2, seed 0; NIST StRD Misra1a, Rat42 and MGH09 from
start 1), at the ML estimate of ``casest.estimate``: casest's 95 % profile intervals of every
parameter, and lmfit's ``conf_interval`` (``leastsq`` fits, the same bounds, its residual written in
NumPy by hand, ``stage2_peers.py``, checked against casest's at the estimate; no casest call in the
peer) given the same statistic through ``prob_func`` (one output, R
unknown: ``N ln(chi2_new / chi2_best)`` against chi-square with one degree of freedom). Both
timed warm in one process, interleaved, the fastest of ``--repeats``; lmfit's time includes its
own fit at the start (``conf_interval`` needs a MinimizerResult). The table gives the largest
relative difference between the two sets of ends.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))
sys.path.insert(0, HERE)

import numpy as np  # noqa: E402
from scipy.stats import chi2  # noqa: E402

import casest  # noqa: E402
from casest.apps.nist import read_nist  # noqa: E402
from casest.two_stage import profile_intervals  # noqa: E402
from stage2_peers import checked_problem  # noqa: E402


def problems():
    """(name, model, data) of the compared problems."""
    for name in ("scalar1", "scalar2"):
        m = casest.load_model_file(name)
        yield name, m.model(), m.simulate(seed=0)
    for name in ("Misra1a", "Rat42", "MGH09"):
        p = read_nist(os.path.join(HERE, "..", "..", "data", "nist_strd", f"{name}.dat"), start=1)
        yield f"{name}/1", p.model, p.data


def lmfit_intervals(model, data, theta, level: float) -> dict:
    """lmfit's conf_interval ends per parameter, with the likelihood-ratio statistic."""
    import lmfit

    params = lmfit.Parameters()
    for p, v in zip(model.parameters, theta):
        params.add(p.name, value=v, min=p.lb, max=p.ub)
    names = model.parameter_names
    numpy_residual, _ = checked_problem(model, data, theta)

    def residual(pars):
        return numpy_residual([pars[n].value for n in names])

    def likelihood_ratio(best, new):
        return chi2.cdf(best.ndata * np.log(new.chisqr / best.chisqr), best.nvarys - new.nvarys)

    minimizer = lmfit.Minimizer(residual, params)
    result = minimizer.minimize(method="leastsq", xtol=1e-12, ftol=1e-12)
    ci = lmfit.conf_interval(minimizer, result, sigmas=[level], prob_func=likelihood_ratio)
    return {n: [v for prob, v in ci[n] if abs(prob - level) < 1e-12] for n in names}


def compare(repeats: int, clock=time.perf_counter) -> list:
    """Per problem: (name, number of parameters, casest s, lmfit s, largest relative difference of
    the ends), each time the fastest of ``repeats`` warm calls by ``clock`` (``time.process_time``
    for CPU seconds), the contenders interleaved, which goes first alternating between calls."""
    rows = []
    for name, model, data in problems():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            problem = casest.Problem(model, data)
            est = casest.estimate(problem)
            ends = {}
            calls = {"casest": lambda: profile_intervals(problem, est.theta, est.R, est.std, level=0.95),
                     "lmfit": lambda: lmfit_intervals(model, data, est.theta, 0.95)}
            times = {"casest": [], "lmfit": []}
            for k in range(repeats + 1):  # the first of each: building and compiling, not counted
                for who in (("casest", "lmfit") if k % 2 == 0 else ("lmfit", "casest")):
                    t = clock()
                    ends[who] = calls[who]()
                    times[who].append(clock() - t)
        ours, theirs = ends["casest"], ends["lmfit"]
        diff = max(abs(a - b) / max(abs(b), 1e-300) for n in model.parameter_names
                   for a, b in zip((ours[n].lower, ours[n].upper), theirs[n]))
        rows.append((name, model.n_parameters, min(times["casest"][1:]), min(times["lmfit"][1:]), diff))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    print("| problem | parameters | casest s | lmfit s | lmfit / casest | largest relative difference of the ends |")
    print("|---|---|---|---|---|---|")
    rows = compare(args.repeats)
    for name, n_parameters, t_ours, t_theirs, diff in rows:
        print(f"| {name} | {n_parameters} | {t_ours:.3f} | {t_theirs:.3f} | {t_theirs / t_ours:.2f} | {diff:.1e} |")
    print()
    print(f"Median lmfit / casest: {np.median([r[3] / r[2] for r in rows]):.2f} ({len(rows)} problems).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
