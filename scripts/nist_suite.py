#!/usr/bin/env python3
"""NIST StRD nonlinear-regression problems under one protocol, casest against SciPy.

    python3 scripts/nist_suite.py [FILES...]     (default: ../shared/data/nist_strd/*.dat,
                                                  else the copies in data/nist_strd/)

Protocol: the only prior knowledge is one of the file's two starts, used as the nominal
value, and a box sign(s) [|s|/1000, 1000 |s|] on every parameter the separator finds
nonlinear (linear parameters get none). Every problem runs from start 1 and from start 2
(``--starts 1`` for one). Per problem and start: the fewest correct significant digits
over the parameters (LRE against the certified values), the RSS ratio to the certified
RSS, the correct digits of the standard deviations (Gauss-Newton with the dof correction,
NIST's convention) and the time; beside them scipy.optimize.least_squares (trf) from the
same start with the same bounds, with finite-difference and with analytic (CasADi)
Jacobians.
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import numpy as np  # noqa: E402

from casest.nist import log_relative_error, read_nist, scipy_least_squares, solve_protocol  # noqa: E402

REPO = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def default_files() -> list:
    for folder in (os.path.join(REPO, "..", "shared", "data", "nist_strd"), os.path.join(REPO, "data", "nist_strd")):
        files = sorted(glob.glob(os.path.join(folder, "*.dat")))
        if files:
            return files
    return []


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("files", nargs="*")
    parser.add_argument("--starts", nargs="+", type=int, choices=[1, 2], default=[1, 2])
    args = parser.parse_args(argv)
    files = args.files or default_files()
    if not files:
        parser.error("no NIST files given or found")
    head = (f"{'problem':<12} {'K':>2} {'xi2':>3} | {'casest digits':>13} {'std digits':>10} {'RSS ratio':>12} {'s':>6} | "
            f"{'scipy-fd dig':>12} {'std':>5} {'s':>6} | {'scipy-an dig':>12} {'std':>5} {'s':>6}")
    print(head)
    print("-" * len(head))
    rows = []
    for path, start in [(p, s) for p in files for s in args.starts]:
        pr = read_nist(path, start=start)
        t = time.perf_counter()
        est = solve_protocol(pr)
        t_casest = time.perf_counter() - t
        digits = log_relative_error(est.theta, pr.certified).min()
        std_digits = log_relative_error(est.std, pr.certified_std).min()
        ratio = pr.rss(est.theta) / pr.certified_rss
        out = [f"{pr.name}/{start}", len(pr.certified), len(pr.certified) - len(pr.linear), digits, std_digits, ratio, t_casest]
        for jac in ("2-point", "analytic"):
            t = time.perf_counter()
            theta, std, _ = scipy_least_squares(pr, jac)
            out += [log_relative_error(theta, pr.certified).min(), log_relative_error(std, pr.certified_std).min(),
                    time.perf_counter() - t]
        rows.append(out)
        print(f"{out[0]:<12} {out[1]:>2} {out[2]:>3} | {out[3]:>13.1f} {out[4]:>10.1f} {out[5]:>12.9f} {out[6]:>6.2f} | "
              f"{out[7]:>12.1f} {out[8]:>5.1f} {out[9]:>6.2f} | {out[10]:>12.1f} {out[11]:>5.1f} {out[12]:>6.2f}")
    names = rows
    rows = np.array([r[1:] for r in rows], dtype=float)
    ok = rows[:, 2] >= 6
    std_ok = rows[:, 3] >= 3
    print("-" * len(head))
    for start in args.starts:
        mine = np.array([r[0].endswith(f"/{start}") for r in names])
        print(f"casest from start {start}: {ok[mine].sum()}/{mine.sum()} problems with >= 6 correct digits in every "
              f"parameter, {std_ok[mine].sum()}/{mine.sum()} with >= 3 digits in every std; "
              f"total {rows[mine, 5].sum():.1f} s")
    for k, name in ((6, "scipy least_squares, finite differences"), (9, "scipy least_squares, analytic Jacobian")):
        print(f"{name}: {(rows[:, k] >= 6).sum()}/{len(rows)} with >= 6 digits, "
              f"{(rows[:, k + 1] >= 3).sum()}/{len(rows)} std >= 3 digits; total {rows[:, k + 2].sum():.1f} s")
    separable_table()
    return 0


def separable_table() -> None:
    """BOD, Puromycin (treated) and Osborne 1 against their published optima, casest and SciPy."""
    from scipy.optimize import least_squares

    import casest

    module = casest.load_model_file(os.path.join(REPO, "models", "separable.py"))
    print()
    print(f"{'data set':<10} | {'casest RSS':>14} {'s':>6} | {'scipy-fd RSS':>14} {'s':>6} | {'published RSS':>13}")
    for name in module.PROBLEMS:
        t = time.perf_counter()
        _, rss = module.solve(name)
        t_c = time.perf_counter() - t
        model, data = module.PROBLEMS[name]()
        f = model.function.map(data.n_samples)
        t = time.perf_counter()
        res = least_squares(lambda th: np.asarray(f(data.signals.T, th)).ravel() - data.outputs[:, 0], model.nominal,
                            bounds=(model.lower_bounds, model.upper_bounds), method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15)
        t_s = time.perf_counter() - t
        print(f"{name:<10} | {rss:>14.7g} {t_c:>6.2f} | {2 * res.cost:>14.7g} {t_s:>6.2f} | {module.PUBLISHED[name]['rss']:>13g}")


if __name__ == "__main__":
    sys.exit(main())
