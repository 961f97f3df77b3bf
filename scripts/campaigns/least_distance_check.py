#!/usr/bin/env python3
"""Random convex QPs ``min 1/2 d' M d + g' d s.t. A d <= b`` for filter error's least-distance
step (:func:`casest.filter_error.least_distance.least_distance_step`), feasible or infeasible by
construction, each answer checked against that truth, its KKT conditions and the optimal value of
an independent solver (qpOASES through CasADi).

    python3 scripts/campaigns/least_distance_check.py [--problems 1000] [--seed 7]

Each problem draws n in 2-8 unknowns and 1-12 rows: M with columns over four decades and an
overall scale over eight, a point x0 over six decades that meets every row (A's rows over six
decades, slacks from 1e-3 to 10 of the row's terms), g placing the unconstrained minimiser
0.1-100 times x0's size away from x0; half the problems add a contradictory pair of rows
(a'd <= beta, -a'd <= -beta - delta, delta from 1e-6 to 10 of the pair's terms at x0). Prints
the counts: feasible and infeasible problems, infeasible ones given a step, feasible ones
refused, steps whose optimal value is above qpOASES's by more than 1e-9 of the terms, steps whose
KKT conditions fail (primal violation above 1e-8 of the row's terms, stationarity above 1e-7 of
its terms' size, complementarity above 1e-7), and the problems on which SciPy's HiGHS linear
programme (absolute tolerances) disagrees with the construction.
"""

from __future__ import annotations

import argparse
import os
import sys

import casadi as ca
import numpy as np
from scipy.optimize import linprog

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from casest.filter_error.least_distance import least_distance_step  # noqa: E402


def random_problem(rng: np.random.Generator) -> tuple:
    """``(M, g, A, b, feasible)`` drawn as the module docstring says; ``feasible`` by construction."""
    n, m = int(rng.integers(2, 9)), int(rng.integers(1, 13))
    B = rng.standard_normal((n, n)) * 10.0 ** rng.uniform(-2, 2, n)  # columns (parameters) over decades
    M = (B.T @ B + 1e-3 * np.diag(np.diag(B.T @ B))) * 10.0 ** rng.uniform(-4, 4)
    x0 = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3)
    # the unconstrained minimiser within 0.1-100 times x0's size of x0
    target = x0 + rng.standard_normal(n) * 10.0 ** rng.uniform(-1, 2) * np.linalg.norm(x0)
    g = -M @ target
    A = rng.standard_normal((m, n)) * (10.0 ** rng.uniform(-3, 3, m))[:, None]
    b = A @ x0 + np.abs(rng.standard_normal(m)) * 10.0 ** rng.uniform(-3, 1) * (np.abs(A) @ np.abs(x0))
    if rng.uniform() < 0.5:
        a = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3)
        beta = a @ x0
        delta = 10.0 ** rng.uniform(-6, 1) * (np.abs(a) @ np.abs(x0) + abs(beta))
        A, b = np.vstack([A, a, -a]), np.concatenate([b, [beta, -beta - delta]])
        return M, g, A, b, False
    return M, g, A, b, True


def kkt_holds(M, g, A, b, d, multipliers) -> bool:
    """Whether ``d`` and its multipliers satisfy the KKT conditions relative to the problem's scale."""
    scale = np.abs(A) @ np.abs(d) + np.abs(b)
    slack = A @ d - b
    stationarity = np.linalg.norm(M @ d + g + A.T @ multipliers)
    size = np.linalg.norm(M @ d) + np.linalg.norm(g) + np.linalg.norm(np.abs(A.T) @ np.abs(multipliers))
    return bool(np.all(slack <= 1e-8 * scale) and stationarity <= 1e-7 * size and np.all(multipliers >= 0)
                and np.all(np.abs(multipliers * slack) <= 1e-7 * multipliers * scale))


#: qpOASES solvers per problem size (each prints its licence banner once, when built)
_QPOASES: dict = {}


def reference_objective(M, g, A, b) -> float | None:
    """The QP's optimal value by qpOASES (through CasADi, rows of unit norm): an active-set solver
    independent of NNLS and HiGHS; None where it fails."""
    norms = np.linalg.norm(A, axis=1)
    if A.shape not in _QPOASES:
        _QPOASES[A.shape] = ca.conic("reference", "qpoases", {"h": ca.Sparsity.dense(*M.shape),
                                                              "a": ca.Sparsity.dense(*A.shape)},
                                     {"printLevel": "none", "error_on_fail": False})
    solver = _QPOASES[A.shape]
    x = np.asarray(solver(h=M, g=g, a=A / norms[:, None], lba=-np.inf, uba=b / norms)["x"]).reshape(-1)
    return float(0.5 * x @ M @ x + g @ x) if solver.stats()["success"] else None


def check(problems: int, seed: int) -> dict:
    """The counts of :func:`main` over ``problems`` problems drawn with ``seed``."""
    rng = np.random.default_rng(seed)
    counts = dict.fromkeys(("feasible", "infeasible", "infeasible given a step", "feasible refused",
                            "objective above qpOASES's", "KKT fails", "HiGHS LP disagrees with the construction"), 0)
    for _ in range(problems):
        M, g, A, b, feasible = random_problem(rng)
        lp = linprog(np.zeros(A.shape[1]), A_ub=A, b_ub=b, bounds=[(None, None)] * A.shape[1], method="highs")
        counts["HiGHS LP disagrees with the construction"] += (lp.status == 0) != feasible
        d, multipliers = least_distance_step(M, g, A, b)
        counts["feasible" if feasible else "infeasible"] += 1
        if d is None:
            counts["feasible refused"] += feasible
        elif not feasible:
            counts["infeasible given a step"] += 1
        else:
            counts["KKT fails"] += not kkt_holds(M, g, A, b, d, multipliers)
            reference, ours = reference_objective(M, g, A, b), 0.5 * d @ M @ d + g @ d
            if reference is not None and ours > reference + 1e-9 * (abs(reference) + abs(g @ d)):
                counts["objective above qpOASES's"] += 1
    return counts


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args(argv)
    counts = check(args.problems, args.seed)
    print(", ".join(f"{k}: {v}" for k, v in counts.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
