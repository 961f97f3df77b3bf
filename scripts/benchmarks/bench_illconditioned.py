#!/usr/bin/env python3
"""Stage 1 on an ill-conditioned linear basis against a well-conditioned one (issue: the QR fallback).

    python3 scripts/benchmarks/bench_illconditioned.py [--candidates 2000] [--reps 2]

The model has 60 linear parameters (Gaussian radial basis functions on x in [0, 1], centres
1/59 apart) and 3 nonlinear ones (the width w, a shift c of the centres, a slope s):
``z = (1 + s x) sum_i a_i exp(-((x - i/59 - c) / w)^2)``, N = 2000 samples. With w in
[0.005, 0.01] the basis functions barely overlap (well conditioned); with w in [0.03, 0.05]
they overlap strongly and the column-scaled normal equations reach condition numbers of
1e10-1e15, so the sweep re-solves those candidates on A itself (the normal equations refined with
exact residuals, column-scaled QR where that does not settle). Both sweeps use the
same number of Sobol candidates; printed: the time of the candidates' evaluation (the design
only, the part the conditioning changes) and of the whole sweep, each as ill / well in the
same process, the number of candidates re-solved on A, and the largest relative difference of
Tr[R] on 40 of the ill-conditioned candidates against QR and against numpy.linalg.lstsq.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time

import casadi as ca
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402
from casest.two_stage.sweep import SweepSettings  # noqa: E402

N1, N_SAMPLES = 60, 2000
WIDTHS = {"well": (0.005, 0.01), "ill": (0.03, 0.05)}


def rbf_problem(width: tuple, seed: int = 0) -> tuple:
    """The radial-basis model with ``w`` in ``width`` and data simulated at the box's middle."""
    x, w, c, s = (ca.SX.sym(n) for n in ("x", "w", "c", "s"))
    a = [ca.SX.sym(f"a{i}") for i in range(N1)]
    h = sum(a[i] * ca.exp(-((x - i / (N1 - 1) - c) / w) ** 2) for i in range(N1)) * (1 + s * x)
    params = [casest.Parameter(f"a{i}", nominal=0.0, prior=casest.Gaussian(0, 1)) for i in range(N1)]
    params += [casest.Parameter("w", lb=width[0], ub=width[1], nominal=float(np.mean(width))),
               casest.Parameter("c", lb=-0.05, ub=0.05, nominal=0.0), casest.Parameter("s", lb=-0.5, ub=0.5, nominal=0.0)]
    model = casest.Model(parameters=params, signals=[casest.Signal("x")], outputs={"z": h}, name="rbf")
    rng = np.random.default_rng(seed)
    xs = rng.uniform(0.0, 1.0, N_SAMPLES)
    truth = {**{f"a{i}": rng.standard_normal() for i in range(N1)}, "w": float(np.mean(width)), "c": 0.01, "s": 0.1}
    z = model.predict(truth, xs[:, None])[:, 0] + 0.01 * rng.standard_normal(N_SAMPLES)
    return model, casest.Dataset(model, {"x": xs, "z": z})


def timed_sweep(model, data, n_candidates: int) -> dict:
    """The sweep's wall time, its design evaluation's, and the candidates re-solved by QR."""
    evaluators = importlib.import_module("casest.two_stage.sweep.evaluators")
    original, stats = evaluators.evaluate_all_candidates, {"design": 0.0}

    def design(*args, **kwargs):
        t0 = time.perf_counter()
        out = original(*args, **kwargs)
        stats["design"] += time.perf_counter() - t0
        stats["fallback"] = args[0].n_fallback if hasattr(args[0], "n_fallback") else 0
        return out

    orchestration = importlib.import_module("casest.two_stage.sweep.orchestration")
    orchestration.evaluate_all_candidates = design
    try:
        t0 = time.perf_counter()
        landscape = casest.sweep(model, data, settings=SweepSettings(n_candidates=n_candidates, design="sobol",
                                                                      error_bound=False))
        stats["sweep"] = time.perf_counter() - t0
    finally:
        orchestration.evaluate_all_candidates = original
    stats["landscape"] = landscape
    return stats


def reference_check(model, data, landscape, count: int = 40) -> tuple[float, float]:
    """Largest relative differences of Tr[R] on ``count`` candidates against column-scaled QR of
    [A, z - b] (casest's QR path alone) and against numpy.linalg.lstsq (SVD)."""
    evaluators = importlib.import_module("casest.two_stage.sweep.evaluators")
    bulk = evaluators.BulkEvaluator(casest.separate(model), data, 64.0, 64)
    rows = np.random.default_rng(1).choice(len(landscape.candidates), count, replace=False)
    _, R_qr, _ = evaluators.evaluate_candidates_qr(bulk, data.outputs, landscape.candidates[rows])
    worst_qr = float(np.max(np.abs(landscape.trace_R[rows] - R_qr[:, 0]) / R_qr[:, 0]))
    worst_svd = 0.0
    for k in rows:
        A, b = bulk(landscape.candidates[[k]])
        y = data.outputs[:, 0] - b[0]
        x = np.linalg.lstsq(A[0], y, rcond=None)[0]
        reference = np.mean((y - A[0] @ x) ** 2)
        worst_svd = max(worst_svd, abs(landscape.trace_R[k] - reference) / reference)
    return worst_qr, worst_svd


def bench(n_candidates: int, reps: int, say=print) -> None:
    """Run the comparison and report through ``say`` (one line per call)."""
    problems = {label: rbf_problem(width) for label, width in WIDTHS.items()}
    timings = {label: [] for label in problems}
    for rep in range(reps):
        for label, (model, data) in problems.items():
            stats = timed_sweep(model, data, n_candidates)
            timings[label].append(stats)
            say(f"rep {rep} {label}: design {stats['design']:.2f} s, sweep {stats['sweep']:.2f} s, "
                  f"re-solved on A {stats.get('fallback', 0)} of {n_candidates}")
    best = {label: (min(s["design"] for s in t), min(s["sweep"] for s in t)) for label, t in timings.items()}
    say(f"ill / well (best of {reps}): design evaluation {best['ill'][0] / best['well'][0]:.2f}x, "
          f"whole sweep {best['ill'][1] / best['well'][1]:.2f}x")
    model, data = problems["ill"]
    worst_qr, worst_svd = reference_check(model, data, timings["ill"][-1]["landscape"])
    say(f"Tr[R] on 40 candidates of the ill-conditioned sweep, largest relative difference: against QR "
          f"{worst_qr:.2e}, against numpy.linalg.lstsq {worst_svd:.2e}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--candidates", type=int, default=2000, help="Sobol candidates per sweep")
    parser.add_argument("--reps", type=int, default=2, help="interleaved repetitions")
    args = parser.parse_args(argv)
    bench(args.candidates, args.reps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
