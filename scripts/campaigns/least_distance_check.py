#!/usr/bin/env python3
"""Random convex QPs ``min 1/2 d' M d + g' d s.t. A d <= b`` for filter error's least-distance
step (:func:`casest.filter_error.practice_steps.least_distance_step`): feasibility decided by an
independent solver (SciPy's HiGHS linear programme), and each returned step checked by its KKT
conditions relative to the problem's scale.

    python3 scripts/campaigns/least_distance_check.py [--problems 1000] [--seed 7]

Each problem draws n in 2-8 unknowns and 1-12 rows, with M, g, A's rows and the point that makes
the rows feasible scaled by powers of ten drawn over several decades; half the problems add a
contradictory pair of rows (a'd <= beta, -a'd <= -beta - delta, delta from 1e-6 to 10 of the
row's scale). Prints the counts: feasible and infeasible problems, infeasible ones given a step
(with the largest violation relative to |A||d| + |b|), feasible ones refused, and steps whose
KKT conditions fail (primal violation above 1e-8 of the scale, stationarity above 1e-7 of its
terms' size, complementarity above 1e-7).
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np
from scipy.optimize import linprog

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from casest.filter_error.practice_steps import least_distance_step  # noqa: E402


def random_problem(rng: np.random.Generator) -> tuple:
    """``(M, g, A, b)`` drawn as the module docstring says."""
    n, m = int(rng.integers(2, 9)), int(rng.integers(1, 13))
    B = rng.standard_normal((n, n))
    M = (B @ B.T + 0.1 * np.eye(n)) * 10.0 ** rng.uniform(-4, 4)
    g = rng.standard_normal(n) * 10.0 ** rng.uniform(-4, 4)
    A = rng.standard_normal((m, n)) * (10.0 ** rng.uniform(-3, 3, m))[:, None]
    x0 = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3)
    b = A @ x0 + np.abs(rng.standard_normal(m)) * 10.0 ** rng.uniform(-3, 1) * np.abs(A @ x0)
    if rng.uniform() < 0.5:
        a = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3)
        beta, delta = a @ x0, abs(a @ x0 + 1.0) * 10.0 ** rng.uniform(-6, 1)
        A, b = np.vstack([A, a, -a]), np.concatenate([b, [beta, -beta - delta]])
    return M, g, A, b


def kkt_holds(M, g, A, b, d, multipliers) -> bool:
    """Whether ``d`` and its multipliers satisfy the KKT conditions relative to the problem's scale."""
    scale = np.abs(A) @ np.abs(d) + np.abs(b)
    slack = A @ d - b
    stationarity = np.linalg.norm(M @ d + g + A.T @ multipliers)
    size = np.linalg.norm(M @ d) + np.linalg.norm(g) + np.linalg.norm(np.abs(A.T) @ np.abs(multipliers))
    return bool(np.all(slack <= 1e-8 * scale) and stationarity <= 1e-7 * size and np.all(multipliers >= 0)
                and np.all(np.abs(multipliers * slack) <= 1e-7 * multipliers * scale))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    counts = dict.fromkeys(("feasible", "infeasible", "infeasible given a step", "feasible refused",
                            "KKT fails"), 0)
    worst = 0.0
    for _ in range(args.problems):
        M, g, A, b = random_problem(rng)
        lp = linprog(np.zeros(A.shape[1]), A_ub=A, b_ub=b, bounds=[(None, None)] * A.shape[1], method="highs")
        feasible = lp.status == 0
        d, multipliers = least_distance_step(M, g, A, b)
        counts["feasible" if feasible else "infeasible"] += 1
        if d is None:
            counts["feasible refused"] += feasible
        elif not feasible:
            counts["infeasible given a step"] += 1
            worst = max(worst, float(np.max((A @ d - b) / (np.abs(A) @ np.abs(d) + np.abs(b)))))
        else:
            counts["KKT fails"] += not kkt_holds(M, g, A, b, d, multipliers)
    print(", ".join(f"{k}: {v}" for k, v in counts.items()),
          f"(largest relative violation of a step given to an infeasible problem: {worst:.3g})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
