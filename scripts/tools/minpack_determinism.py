#!/usr/bin/env python3
"""Is SciPy's MINPACK (``scipy.optimize.leastsq``, lmder) deterministic within one process?

    python3 scripts/tools/minpack_determinism.py [--runs 60]

Each of five NIST StRD problems (from start 1, the model's exact Jacobian from CasADi) is
solved ``--runs`` times in one process with heap churn between the runs (arrays of random
sizes allocated and freed), and each run's solution and evaluation count are hashed: one
distinct hash per problem means the same answer every time. The callbacks are then run again
returning one reused buffer each (what an in-place evaluation through a CasADi buffer does),
which must give the same bits as fresh arrays. Finally the Jacobian is handed over, as casest's MINPACK wrapper before 6a2d5e5 did, from the
last point whose residuals were evaluated rather than computed at the point MINPACK asks for
(lmder asks for it only after evaluating that point, so both must give the same iterates).
Last, the generated net's problem 164 (three exponentials in a flat valley, where ``qrfac``
recomputes a column's norm): SciPy 1.15-1.17 read one element past the Jacobian there
(scipy/scipy#24323), so its results depend on the heap; with a last Jacobian column of zeros
appended (what casest hands MINPACK) they must not.

Prints one line per check; exits 1 if any problem gives more than one distinct result.
"""

from __future__ import annotations

import argparse
import glob
import hashlib
import os
import sys

import casadi as ca
import numpy as np
from scipy.optimize import leastsq

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
sys.path.insert(0, ROOT)

from casest.apps.nist import read_nist  # noqa: E402
from casest.models.modelfile import bundled_data_dir  # noqa: E402

PROBLEMS = ("Bennett5", "MGH09", "Lanczos3", "Gauss1", "Thurber")
TOL = 1e-15


def nist_problem(name: str, start: int = 1):
    """(residual, Jacobian, start) of a NIST problem: NumPy callbacks over CasADi's exact derivatives."""
    path = next(p for p in glob.glob(bundled_data_dir("nist_strd*", "*.dat")) if os.path.basename(p) == name + ".dat")
    pr = read_nist(path, start=start)
    model, data = pr.model, pr.data
    signals, outputs = data.signals.T, data.filled_outputs().ravel()
    function = model.jacobian_function

    def residual(theta):
        h, _ = function(signals, theta)
        return outputs - np.asarray(h).ravel()

    def jacobian(theta):
        _, J = function(signals, theta)
        return -np.asarray(ca.densify(J)).reshape(-1, model.n_parameters, order="F")

    return residual, jacobian, np.clip(model.nominal, model.lower_bounds, model.upper_bounds)


def solve(residual, jacobian, x0, maxfev: int = 2000) -> tuple[np.ndarray, int]:
    x, _, info, _, _ = leastsq(residual, x0.copy(), Dfun=jacobian, full_output=True, xtol=TOL, ftol=TOL,
                               gtol=0.0, maxfev=maxfev)
    return x, int(info["nfev"])


def digest(x: np.ndarray, nfev: int) -> str:
    return hashlib.sha256(x.tobytes() + str(nfev).encode()).hexdigest()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=60)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    ok = True
    for name in PROBLEMS:
        residual, jacobian, x0 = nist_problem(name)
        seen, churn = set(), []
        for _ in range(args.runs):
            churn.append(np.empty(int(rng.integers(1, 100_000))))
            if len(churn) > 10:
                churn.pop(0)
            seen.add(digest(*solve(residual, jacobian, x0)))
        fresh = solve(residual, jacobian, x0)
        buffers: dict = {}

        def reused(fun, key):
            def call(theta):
                value = fun(theta)
                buffer = buffers.setdefault(key, np.empty_like(value))
                buffer[...] = value
                return buffer
            return call

        aliased = solve(reused(residual, "r"), reused(jacobian, "J"), x0)
        last: dict = {}

        def residual_keeping_jacobian(theta):
            last["J"] = jacobian(theta)
            return residual(theta)

        stale = solve(residual_keeping_jacobian, lambda theta: last["J"], x0)
        ok &= len(seen) == 1
        print(f"{name:<9} distinct results over {args.runs} runs: {len(seen)}; reused buffers give the same bits: "
              f"{np.array_equal(aliased[0], fresh[0]) and aliased[1] == fresh[1]}; the Jacobian of the last "
              f"evaluated point: {'same' if np.array_equal(stale[0], fresh[0]) else 'other'} iterates "
              f"({stale[1]} evaluations against {fresh[1]})")
    ok &= heap_check(args.runs, rng)
    return 0 if ok else 1


def net_problem_164():
    """(residual, Jacobian, start) of the generated net's problem 164 (one output, R at the start's residual
    mean square) as casest hands it to MINPACK: scaled parameters mapped onto unbounded ones."""
    sys.path.insert(0, os.path.join(ROOT, "scripts", "campaigns"))
    from nets.optimum_net import net_problem
    from casest import Problem
    from casest.two_stage.solve.levenberg_marquardt import BoundMap, WeightedResiduals

    pr = net_problem(164)
    model = pr.model
    problem = Problem(model, pr.data)
    _, R0 = problem.start_point(model.nominal, np.array([1e-20]))
    residuals, scale = WeightedResiduals(problem), model.scales
    bounds, weights = BoundMap(model.lower_bounds / scale, model.upper_bounds / scale), 1.0 / np.sqrt(R0)

    def residual(u):
        s, _ = bounds.x_and_slope(u)
        return residuals(s * scale, weights)[0].copy()

    def jacobian(u):
        s, slope = bounds.x_and_slope(u)
        return -(residuals(s * scale, weights)[1] * (scale * slope))

    return residual, jacobian, bounds.u_of(np.asarray(model.nominal, dtype=float) / scale)


def with_zero_column(residual, jacobian, x0):
    """The same problem with one more parameter that enters no residual (its Jacobian column zero, last)."""
    n = x0.size
    return (lambda x: residual(x[:n]), lambda x: np.column_stack([jacobian(x[:n]), np.zeros(len(residual(x[:n])))]),
            np.append(x0, 0.0))


def heap_check(runs: int, rng) -> bool:
    """Distinct results of problem 164 over ``runs`` solves with heap churn, as given and with the zero column."""
    plain = net_problem_164()
    padded = with_zero_column(*plain)
    counts = []
    for residual, jacobian, x0 in (plain, padded):
        seen, churn = set(), []
        for _ in range(runs):
            churn.append(np.empty(int(rng.integers(1, 100_000))))
            if len(churn) > 10:
                churn.pop(0)
            # a freed block of the Jacobian's size with random content where MINPACK's copy will be allocated
            del churn[-1]
            junk = rng.standard_normal(len(residual(x0)) * x0.size + 1)
            del junk
            x, nfev = solve(residual, jacobian, x0, maxfev=151)  # casest's budget with max_iter=150
            seen.add(digest(x[:plain[2].size], nfev))
        counts.append(len(seen))
    print(f"net 164   distinct results over {runs} runs: {counts[0]} as given, {counts[1]} with a zero column appended")
    return counts[1] == 1


if __name__ == "__main__":
    sys.exit(main())
