"""The estimator inside CasADi graphs: one local solve against the two-stage Function.

On scalar example 2 (paper Sec. III.B, competing local minima), for 10 records and 3
starts: does `estimator_function` (one IPOPT solve from a start) reach the global ML
cost, and does `two_stage_function` (stage 1 + stage 2, as `casest.estimate`)? The global
cost is the best of both and of a dense stage 1 (4096 Sobol candidates). Then the
two-stage Function's data derivatives (implicit function theorem) against central
differences of the Function itself.

    python3 scripts/paper/two_stage_vs_one_solve.py
"""

from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casadi as ca  # noqa: E402

import casest  # noqa: E402
from casest.interop import estimator_function, two_stage_function  # noqa: E402

STARTS = [np.array([0.0, 0.0, 0.0, 0.0]), np.array([0.5, 0.25, 0.5, 0.5]), np.array([-1.0, 0.4, 0.9, -1.0])]


def compare(m, seeds=range(10)) -> tuple[int, int, list]:
    """(one-solve hits of 3 x len(seeds) pairs, two-stage hits of len(seeds) records, rows)."""
    model = m.model()
    N = m.simulate(0).n_samples
    one, two = estimator_function(model, N), two_stage_function(model, N)
    one_hits, two_hits, rows = 0, 0, []
    for seed in seeds:
        data = m.simulate(seed)
        X, Z = data.signals.T, data.outputs.T
        theta, R, _, ok = (np.asarray(v).ravel() for v in two(X, Z))
        assert ok[0] == 1.0, f"seed {seed}: the two-stage Function reports no success"
        J_two = casest.ml_cost(model, data, theta, R)
        J_one = [casest.ml_cost(model, data, *(np.asarray(v).ravel() for v in one(X, Z, s))) for s in STARTS]
        dense = casest.estimate(model, data, sweep_settings=casest.SweepSettings(design="sobol", n_candidates=4096))
        best = min([J_two, dense.cost] + J_one)
        tol = 1e-7 * abs(best)
        two_hits += J_two <= best + tol
        one_hits += sum(J <= best + tol for J in J_one)
        rows.append((seed, best, J_two, J_one))
    return one_hits, two_hits, rows


def main() -> dict:
    m = casest.load_model_file("scalar2")
    model = m.model()
    N = m.simulate(0).n_samples
    two = two_stage_function(model, N)
    one_hits, two_hits, rows = compare(m)
    print(f"{'seed':>4} {'global J':>10} {'two-stage J':>12} {'one solve J (3 starts)':>32}")
    for seed, best, J_two, J_one in rows:
        print(f"{seed:4d} {best:10.4f} {J_two:12.4f} " + " ".join(f"{J:10.4f}" for J in J_one))
    print(f"global ML cost reached: one solve {one_hits} of 30 (seed, start) pairs; two-stage {two_hits} of 10 "
          "records (it takes no start: all 30 pairs)")

    data = m.simulate(0)
    X0, Z0 = data.signals.T.copy(), data.outputs.T.copy()
    Xs, Zs = ca.MX.sym("X", 1, N), ca.MX.sym("Z", 1, N)
    out = two(Xs, Zs)
    wanted = ca.vertcat(out[0], out[1], ca.vec(out[2]))
    dX, dZ = (np.asarray(v) for v in ca.Function("d", [Xs, Zs], [ca.jacobian(wanted, Xs), ca.jacobian(wanted, Zs)])(X0, Z0))
    value = ca.Function("value", [Xs, Zs], [wanted])
    worst = {"theta": 0.0, "R": 0.0, "cov": 0.0}
    h = 1e-6
    for k in range(0, N, 10):
        for analytic, which in ((dX, 0), (dZ, 1)):
            plus, minus = [X0.copy(), Z0.copy()], [X0.copy(), Z0.copy()]
            plus[which][0, k] += h
            minus[which][0, k] -= h
            fd = (np.asarray(value(*plus)) - np.asarray(value(*minus))).ravel() / (2 * h)
            for name, rows in (("theta", slice(0, 4)), ("R", slice(4, 5)), ("cov", slice(5, None))):
                err = np.abs(analytic[rows, k] - fd[rows]).max() / max(np.abs(fd[rows]).max(), 1e-300)
                worst[name] = max(worst[name], err)
    print("data derivatives against central differences (h = 1e-6, every 10th sample of signals and outputs), "
          "largest error relative to the column's largest entry: "
          + ", ".join(f"{k} {v:.1e}" for k, v in worst.items()))
    return {"one": one_hits, "two": two_hits, "derivative_error": worst}


if __name__ == "__main__":
    main()
