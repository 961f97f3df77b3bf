#!/usr/bin/env python3
"""Performance benchmarks, all in one process on the same data (ratios, not timed tests).

    python3 scripts/benchmarks/bench.py [--quick] [--parts cold stage1 stage2 dynamic flight filters scaling illcond] [--out docs/benchmarks.md]

cold     Cold start on the Pitot default in fresh processes: import casest, the first estimate,
         an estimate with a fresh model object, a warm estimate, each with its C compiles, with an
         empty compile cache and with the cache the first process filled.

stage1   Stage-1 throughput (candidate x sample evaluations per second) on the Pitot model,
         N = 1e3, 1e4, 1e5 samples and K = 500, 5000 candidates: casest's sweep (uncompiled
         NumPy arrays and JIT) against a loop of one numpy.linalg.lstsq per candidate (A and b from the
         same CasADi functions); peak traced memory; the share of the machine's dense BLAS
         rate (a matrix product measured here) that the batched least squares reach; and
         against the same sweep in vectorised NumPy and in JAX (jit of vmap), checked equal.
stage2   Time to solution and success of casest (full pipeline, and stage 2 alone from the
         same start; cold and warm) against scipy.optimize.least_squares (trf) and lmfit
         (leastsq, if installed), each with the exact Jacobian (NumPy, written by hand in
         scripts/benchmarks/stage2_peers.py and checked against casest's) and with finite differences,
         on scalar 2, the Pitot problem (plain LS and ML by per-channel reweighting for the
         peers; all judged by the ML cost) and the bundled NIST problems from both starts.
flight   scripts/benchmarks/bench_output_error.py: the bundled dynamic files with the Gauss-Newton and IPOPT
         output-error paths; the 38-parameter aircraft output error, cold and warm, both paths,
         against JAX + SciPy least_squares in the same run; filter-error ML on the 4-state
         longitudinal record in its three formulations and with both solvers.
filters  scripts/benchmarks/bench_filters.py: the EKF over a 1e4-sample pendulum record, casest's compiled pass
         (cold and warm) and its step-by-step loop against filterpy and a JAX lax.scan EKF.
dynamic  Dynamic models: stage-1 candidate x sample rate through the ODE (data compatibility,
         N = 5000 samples, 4096 Sobol candidates of the six IMU biases; CasADi VM and compiled),
         and output-error stage 2 of the short-period model at N = 1e4 from the same start:
         cold (a fresh process: build, compile, solve) and warm (the next record in the same
         process), against a SciPy fit of the same problem (solve_ivp of the states and their
         sensitivities interval by interval, least_squares with that Jacobian, reweighted per
         channel to the ML fixed point).
scaling  Stage-2 time per IPOPT iteration and peak memory on the Pitot model as N grows
         from 1e2 to 1e6 (longer records repeat the flight with fresh noise), with the
         fitted log-log slope.
"""

from __future__ import annotations

import argparse
import glob
import os
import platform
import sys
import time
import tracemalloc
import warnings

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402

import casest  # noqa: E402
from casest.estimation.sweep import draw_candidates  # noqa: E402
from casest.backend.array_sums import ArraySum  # noqa: E402
from casest.estimation.sweep.evaluators import GramEvaluator, evaluate_candidates  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.join(HERE, "..", "..")
LINES: list = []
READING = "## Reading the figures"


def cold_state() -> None:
    """As a fresh process with an empty compile cache: casest's in-process caches cleared, the
    compile cache pointed at a new empty folder (removed at exit)."""
    import atexit
    import shutil
    import tempfile

    from casest._casadi.memory import clear_memory_caches

    folder = tempfile.mkdtemp(prefix="casest_bench_cache_")
    atexit.register(shutil.rmtree, folder, True)
    os.environ["CASEST_CACHE_DIR"] = folder
    clear_memory_caches()


def say(text: str = "") -> None:
    print(text, flush=True)
    LINES.append(text)


def pitot_data(n: int, seed: int = 0):
    """A Pitot record of n samples: the simulated flight, repeated with fresh noise if longer."""
    module = casest.load_model_file(os.path.join(REPO, "models", "pitot5hole.py"))
    model = module.model()
    base = module.simulate(seed)
    if n <= base.n_samples:
        return module, model, base.subset(slice(0, n))
    parts, k = [], 0
    while sum(p.n_samples for p in parts) < n:
        parts.append(module.simulate(seed + k))
        k += 1
    signals = np.vstack([p.signals for p in parts])[:n]
    outputs = np.vstack([p.outputs for p in parts])[:n]
    return module, model, casest.Dataset.from_arrays(model, signals, outputs)


# ----------------------------------------------------------------------------- stage 1
def blas_rate() -> float:
    """GFLOP/s of a dense matrix product on this machine (best of 3)."""
    a = np.random.default_rng(0).standard_normal((2000, 2000))
    best = np.inf
    for _ in range(3):
        t = time.perf_counter()
        a @ a
        best = min(best, time.perf_counter() - t)
    return 2 * 2000**3 / best / 1e9


def gram_kernel(evaluator, xi2, N: int, ny: int, n1: int, jit: bool):
    """The sweep's Gram products as a compiled map-reduce over stored rows [A_k, y_k]."""
    from casest.backend.sums import map_sum

    bulk = evaluator.bulk
    A, b = bulk(xi2[None, :])
    y = evaluator.data.outputs.reshape(-1) - b[0]
    rows = np.concatenate([A[0], y[:, None]], axis=1).reshape(N, ny * (n1 + 1))  # per sample
    m = ca.SX.sym("m", ny * (n1 + 1))
    r, c = np.triu_indices(n1 + 1)
    T = len(r)
    # the entries the sweep sums (those that are not constant per sample), column-major t + T*j
    products = ca.vertcat(*[m[(k // T) * (n1 + 1) + r[k % T]] * m[(k // T) * (n1 + 1) + c[k % T]]
                            for k in evaluator._varying])
    # map_sum takes two per-sample inputs; the second is a placeholder
    per_sample = ca.Function("gram_rows", [m, ca.SX.sym("u", 1)], [products])
    if isinstance(evaluator._lanes, ArraySum):  # uncompiled: the same products as NumPy operations
        return ArraySum.build(per_sample, [rows]), None
    if evaluator._lanes is not None:  # the sweep's SIMD sums: the same products, four candidates per pass
        from casest.backend.lane_sums import LaneSum

        lanes = LaneSum.build(per_sample, [rows], "gram_rows_lanes")
        return lanes, None
    kernel = map_sum(per_sample, N, 1, "gram_rows_sum", jit, ("-O3", "-march=native"), n_data=2)
    args = [np.ascontiguousarray(rows).reshape(-1), np.zeros(N)]
    return kernel, args


def _time_lanes(lanes, reps: int, threads: int = 1) -> float:
    """Seconds per candidate of the SIMD (or NumPy array) sums when ``threads`` threads call them
    concurrently: four candidates a call (one SIMD group), a block of them for the array sums."""
    from concurrent.futures import ThreadPoolExecutor

    per_call = lanes.block if isinstance(lanes, ArraySum) else 4
    reps = max(1, reps * 4 // per_call)
    values = np.zeros((per_call, 1))
    with ThreadPoolExecutor(threads) as pool:
        t = time.perf_counter()
        list(pool.map(lambda _: [lanes(values) for _ in range(reps)], range(threads)))
        return (time.perf_counter() - t) / (per_call * reps)


def _time_buffer(fun, args, reps: int, threads: int = 1) -> float:
    """Seconds per call of ``fun`` when ``threads`` threads call it concurrently (as the sweep does)."""
    from concurrent.futures import ThreadPoolExecutor

    runs, keep = [], []
    for _ in range(threads):
        buffer, run = fun.buffer()
        out = [np.zeros(fun.nnz_out(k)) for k in range(fun.n_out())]
        for k, a in enumerate(args):
            buffer.set_arg(k, memoryview(a))
        for k, o in enumerate(out):
            buffer.set_res(k, memoryview(o))
        run()
        runs.append(run)
        keep.append((buffer, out))

    def loop(run):
        for _ in range(reps):
            run()

    with ThreadPoolExecutor(threads) as pool:
        t = time.perf_counter()
        list(pool.map(loop, runs))
        return (time.perf_counter() - t) / (reps * threads)


def same_shape_rate(N: int, ny: int, n_cols: int) -> float:
    """GFLOP/s of the BLAS product M'M for one stage-1 problem's shape, M (N*ny x n_cols)."""
    M = np.random.default_rng(0).standard_normal((N * ny, n_cols))
    reps = max(20, int(2e7 // (N * ny * n_cols * n_cols)))
    best = np.inf
    for _ in range(3):
        t = time.perf_counter()
        for _ in range(reps):
            M.T @ M
        best = min(best, (time.perf_counter() - t) / reps)
    return 2 * N * ny * n_cols * n_cols / best / 1e9


def bench_stage1(quick: bool) -> None:
    say("## Stage 1: throughput on the Pitot model")
    say()
    rate = blas_rate()
    say(f"Dense matrix product (2000 x 2000, NumPy BLAS, both cores): {rate:.1f} GFLOP/s.")
    say()
    say("Loop: for each candidate, A and b from the model's CasADi functions mapped over the samples, then "
        "`numpy.linalg.lstsq`. casest: `SweepSettings()` defaults (Gram method; JIT from N x K >= "
        f"{casest.SweepSettings().jit_min_work:.0e}; "
        "threads over candidates, one per core), time of the evaluation of all candidates after the build.")
    say()
    say("| N | K | loop s/cand. | casest uncompiled s | casest default s (build) | speed-up vs loop | cand.×samples/s | "
        "LS GFLOP/s (% of GEMM peak) | same-shape BLAS GFLOP/s (LS %) | LS share of sweep (upper bound) | QR fallbacks | peak traced MiB |")
    say("|---|---|---|---|---|---|---|---|---|---|---|---|")
    sizes = [(1000, 500), (1000, 5000), (10000, 500), (10000, 5000), (100000, 500)]
    if not quick:
        sizes.append((100000, 5000))
    for N, K in sizes:
        module, model, data = pitot_data(N)
        part = casest.separate(model)
        cands, _, _ = draw_candidates(model, part, casest.SweepSettings(design="random", n_candidates=K, seed=1))
        # baseline: one lstsq per candidate, A and b from the same CasADi functions (VM)
        A_f, b_f = part.A.map(N), part.b.map(N)
        X = data.signals.T
        z = data.outputs.reshape(-1)
        n_loop = 20 if N <= 10000 else 5
        t = time.perf_counter()
        for c in cands[:n_loop]:
            A = np.asarray(A_f(X, c)).reshape(3, N, -1).transpose(1, 0, 2).reshape(N * 3, -1)
            b = np.asarray(b_f(X, c)).T.reshape(-1)
            np.linalg.lstsq(A, z - b, rcond=None)
        loop = (time.perf_counter() - t) / n_loop
        settings = casest.SweepSettings()
        jit, threads = settings.resolved_jit(N, K), settings.resolved_threads(K)
        vm = "-"
        if N * K <= 5e6:
            ev = GramEvaluator(part, data, K, jit=False, threads=threads)
            t = time.perf_counter()
            evaluate_candidates(ev, data.outputs, cands)
            vm = f"{time.perf_counter() - t:.2f}"
        tracemalloc.start()
        t = time.perf_counter()
        ev = GramEvaluator(part, data, K, jit=jit, threads=threads)
        build = time.perf_counter() - t
        t = time.perf_counter()
        evaluate_candidates(ev, data.outputs, cands)
        sweep_s = time.perf_counter() - t
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        # least-squares part: the sweep's Gram-product code (same SX products, same compiled
        # map-reduce, same threads) run alone on one candidate's [A, y], plus the small solves
        n1, ny = part.n_linear, model.n_outputs
        ls_kernel, ls_args = gram_kernel(ev, cands[0], N, ny, n1, jit)
        n_products = len(ev._varying)
        reps = max(5, int(2e7 // (N * n_products)))
        if ls_args is None:
            t_kernel = min(_time_lanes(ls_kernel, reps, threads) for _ in range(3))
        else:
            t_kernel = min(_time_buffer(ls_kernel, ls_args, reps, threads) for _ in range(3))
        G = ev.gram(cands[: min(K, 1000)])
        t = time.perf_counter()
        P = G[:, :, :n1, :n1].sum(axis=1)
        np.linalg.eigvalsh(P)
        np.linalg.solve(P, G[:, :, :n1, n1].sum(axis=1)[..., None])
        t_small = (time.perf_counter() - t) / len(G)
        ls_time = t_kernel + t_small
        ls_rate = 2 * N * n_products / ls_time / 1e9
        share = ls_time * K / sweep_s
        shape_rate = same_shape_rate(N, ny, n1 + 1)
        say(f"| {N} | {K} | {loop:.4f} | {vm} | {sweep_s:.2f} ({build:.1f}) | {loop * K / sweep_s:.1f}x | "
            f"{N * K / sweep_s:.3g} | {ls_rate:.1f} ({100 * ls_rate / rate:.0f}%) | {shape_rate:.1f} ({100 * ls_rate / shape_rate:.0f}%) | "
            f"{100 * share:.0f}% | {ev.n_fallback} | {peak:.0f} |")
    say()
    say("LS GFLOP/s: 2 N P flops for the P Gram entries the sweep sums per sample (of the m T = 3 x 21 per-channel "
        "entries of [A, y]'[A, y], those that are not constant: P = 27 here, the wind columns of A being zeros "
        "and ones) over the time of the sweep's product code (the same products, the same SIMD sums or map-reduce, threads) "
        "run alone on one candidate's stored rows [A, y], on as many threads at once, plus the normal-equation solves per candidate. In the "
        "sweep the products are fused into the evaluation, so they cost less there. LS share: that time x K over "
        "the sweep time (an upper bound, for that reason). "
        "GEMM peak: the 2000 x 2000 product above; "
        "same-shape BLAS: NumPy's `M.T @ M` for one candidate's M = [A, y] (N m x (n1 + 1)), the BLAS product "
        "of the size the least squares work on.")
    say()
    bench_stage1_peers(quick)
    bench_bounded_ranking()


def pitot_sweep_inputs(module, data):
    """Per-sample arrays of the Pitot sweep that do not depend on the candidates."""
    cols = {n: data.signals[:, k] for k, (n, _) in enumerate(module.SIGNALS)}
    qc = cols["P_t"] - cols["P_s"]
    speed = np.sqrt(2 * qc / module.RHO)
    ph, th, ps = cols["phi"], cols["theta"], cols["psi"]
    from casest.apps.sim.flight import dcm_body_to_ned

    C = np.array([dcm_body_to_ned(a, b, c) for a, b, c in zip(ph, th, ps)])  # (N, 3, 3)
    omega = np.column_stack([cols["p"] - cols["b_gx"], cols["q"] - cols["b_gy"], cols["r"] - cols["b_gz"]])
    lever = np.einsum("nij,nj->ni", C, np.cross(omega, np.asarray(module.LEVER_ARM)))
    return {"pa": cols["P_alpha"] / (module.K_ALPHA * qc), "pb": cols["P_beta"] / (module.K_BETA * qc),
            "speed": speed, "C": C, "lever": lever, "z": data.outputs, "deg": module.DEG}


def bench_stage1_peers(quick: bool) -> None:
    """casest's sweep against the competent NumPy and JAX peers (scripts/benchmarks/stage1_peers.py), per thread too."""
    import stage1_peers as peers

    say("### Stage 1 against vectorised NumPy and JAX")
    say()
    say("The same Pitot sweep (Tr[R] at each candidate, xi1 unconstrained) written as a competent user would "
        "(`scripts/benchmarks/stage1_peers.py`): the model's algebra reduced by hand to two BLAS products per channel and "
        "chunk of 8 candidates with batched, column-scaled 5x5 normal equations, in NumPy (1 and 2 threads over "
        "chunks) and the same algebra under `jax.jit` (chunks of 50, CPU, float64). Each is checked equal to "
        "casest's Tr[R] (largest relative difference shown). Times: the sweep after the build (casest: "
        "`SweepSettings()` evaluator, compiled, with 1 and 2 threads; JAX: after a first call that compiles); "
        "the best of three interleaved repetitions. A ratio above 1 means casest is faster.")
    say()
    say("| N | K | casest 1 thr s | casest 2 thr s | NumPy 1 thr s | NumPy 2 thr s | JAX s (compile) | "
        "NumPy / casest, 1 thr | NumPy / casest, 2 thr | JAX / casest 2 thr | max rel. diff |")
    say("|---|---|---|---|---|---|---|---|---|---|---|")
    sizes = [(1000, 5000), (10000, 5000), (100000, 500)] if not quick else [(1000, 5000), (10000, 500)]
    for N, K in sizes:
        module, model, data = pitot_data(N)
        part = casest.separate(model)
        cands, _, _ = draw_candidates(model, part, casest.SweepSettings(design="random", n_candidates=K, seed=1))
        jit = casest.SweepSettings().resolved_jit(N, K)
        evaluators = {t: GramEvaluator(part, data, K, jit=jit, threads=t) for t in (1, 2)}
        inp = peers.peer_inputs(pitot_sweep_inputs(module, data))
        numpy_sweep = peers.NumpySweep(inp, chunk=8)
        jax_run = None
        try:
            jax_run = peers.jax_batched_factory(inp, 50)
            t = time.perf_counter()
            jax_run(cands[:50])
            t_compile = time.perf_counter() - t
        except ImportError:
            pass
        times = {k: [] for k in ("c1", "c2", "n1", "n2", "jax")}
        diffs = []
        for _ in range(3):
            for threads in (1, 2):
                t = time.perf_counter()
                _, R, _ = evaluate_candidates(evaluators[threads], data.outputs, cands)
                times[f"c{threads}"].append(time.perf_counter() - t)
            trace = R.sum(axis=1)
            for threads in (1, 2):
                t = time.perf_counter()
                tr = numpy_sweep.trace(cands, threads)
                times[f"n{threads}"].append(time.perf_counter() - t)
                diffs.append(np.max(np.abs(tr - trace) / trace))
            if jax_run is not None:
                t = time.perf_counter()
                tr = jax_run(cands)
                times["jax"].append(time.perf_counter() - t)
                diffs.append(np.max(np.abs(tr - trace) / trace))
        best = {k: min(v) if v else float("nan") for k, v in times.items()}
        jax_cell = f"{best['jax']:.2f} ({t_compile:.1f})" if jax_run is not None else "not installed"
        say(f"| {N} | {K} | {best['c1']:.2f} | {best['c2']:.2f} | {best['n1']:.2f} | {best['n2']:.2f} | {jax_cell} | "
            f"{best['n1'] / best['c1']:.2f} | {best['n2'] / best['c2']:.2f} | {best['jax'] / best['c2']:.2f} | "
            f"{max(diffs):.1e} |")
    say()


def bench_bounded_ranking(reps: int = 5) -> None:
    """What ranking candidates by the best feasible xi1 costs: the same evaluation with and without bounds."""
    hard = casest.load_model_file(os.path.join(REPO, "models", "robustness.py"))
    model, data = hard.triad(0)
    part = casest.separate(model)
    cands, *_ = draw_candidates(model, part, casest.SweepSettings(n_candidates=2000))
    ev = GramEvaluator(part, data, len(cands), False, 1)
    lin = list(part.linear_index)
    lb, ub = model.lower_bounds[lin], model.upper_bounds[lin]
    free, bounded = [], []
    for _ in range(reps):
        t = time.perf_counter()
        x0, _, _ = evaluate_candidates(ev, data.outputs, cands)
        free.append(time.perf_counter() - t)
        t = time.perf_counter()
        evaluate_candidates(ev, data.outputs, cands, lb, ub)
        bounded.append(time.perf_counter() - t)
    outside = int(np.any((x0 < lb) | (x0 > ub), axis=1).sum())
    say("### Bound-aware ranking")
    say()
    say(f"Triad model (`models/robustness.py`, N = {data.n_samples}, 6 linear parameters, |s| <= 0.1), "
        f"{len(cands)} candidates, one thread, uncompiled (NumPy arrays), median of {reps}: without the linear bounds "
        f"{np.median(free):.4f} s, with them {np.median(bounded):.4f} s (ratio {np.median(bounded) / np.median(free):.2f}); "
        f"{outside} of {len(cands)} candidates have an unconstrained xi1 outside the box and get the batched "
        "box-constrained least squares on their Gram matrices.")
    say()


# ----------------------------------------------------------------------------- stage 2
# Peers get what casest gets: the same start (the model's nominal values), the same box, the
# exact Jacobian written by hand in NumPy (or finite differences, both stated), and on multi-channel problems
# the same criterion: the ML cost with unknown diagonal R, which a least-squares code reaches
# by per-channel reweighting to convergence (Gauss-Newton-like iteratively reweighted LS).
def _residual_functions(model, data, start):
    """The peers' NumPy residual and hand-written Jacobian (scripts/benchmarks/stage2_peers.py), checked against
    casest's at the start: no CasADi call inside the peers' fits."""
    import stage2_peers

    pitot = casest.load_model_file(os.path.join(REPO, "models", "pitot5hole.py")) if model.name == "pitot5hole" \
        else None
    return stage2_peers.checked_problem(model, data, np.clip(start, model.lower_bounds, model.upper_bounds), pitot)


def _reweighted(fit, model, data, start, res, rounds: int = 50):
    """ML by per-channel reweighting: weighted LS with w_j = 1/sqrt(R_j), R from the (NumPy) residuals."""
    ny = model.n_outputs
    if ny == 1:
        return fit(start, np.ones(1))
    weights, theta, total = np.ones(ny), start, 0.0
    for _ in range(rounds):
        theta, dt = fit(theta, weights)
        t = time.perf_counter()
        ms = np.mean(res(theta).reshape(-1, ny) ** 2, axis=0)
        total += dt + time.perf_counter() - t
        new = 1.0 / np.sqrt(np.maximum(ms, 1e-300))
        if np.allclose(new, weights, rtol=1e-10):
            break
        weights = new
    return theta, total


def scipy_fit(model, data, start, jac: str, ml: bool, max_nfev: int = 20000):
    """scipy.optimize.least_squares, trf, x_scale='jac', tolerances 1e-15, at most ``max_nfev`` evaluations."""
    from scipy.optimize import least_squares

    res, jac_fn = _residual_functions(model, data, start)
    lb, ub = model.lower_bounds, model.upper_bounds
    inner_lb = np.where(np.isfinite(lb), lb + 1e-10 * np.maximum(1, np.abs(lb)), lb)
    inner_ub = np.where(np.isfinite(ub), ub - 1e-10 * np.maximum(1, np.abs(ub)), ub)

    def fit(theta, weights):
        w = np.tile(weights, data.n_samples)
        theta = np.clip(theta, inner_lb, inner_ub)  # trf needs a strictly feasible start
        t = time.perf_counter()
        out = least_squares(lambda th: res(th) * w, theta,
                            jac=(lambda th: jac_fn(th) * w[:, None]) if jac == "analytic" else "2-point",
                            bounds=(lb, ub), method="trf", x_scale="jac", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                            max_nfev=max_nfev)
        return out.x, time.perf_counter() - t

    return _reweighted(fit, model, data, start, res) if ml else fit(start, np.ones(model.n_outputs))


def _lmfit_fit(model, data, start, jac: str, ml: bool):
    """lmfit leastsq (MINPACK LM; bounds by lmfit's transform), Dfun analytic or its default
    finite differences (epsfcn 1e-10), tolerances 1e-15."""
    import lmfit

    res, jac_fn = _residual_functions(model, data, start)
    names = model.parameter_names

    def fit(theta, weights):
        w = np.tile(weights, data.n_samples)
        params = lmfit.Parameters()
        for p, s in zip(model.parameters, theta):
            params.add(p.name, value=float(np.clip(s, p.lb, p.ub)), min=p.lb, max=p.ub)

        def vec(pars):
            return np.array([pars[n].value for n in names])

        kws = {"Dfun": lambda pars: jac_fn(vec(pars)) * w[:, None]} if jac == "analytic" else {}
        t = time.perf_counter()
        out = lmfit.minimize(lambda pars: res(vec(pars)) * w, params, method="leastsq", xtol=1e-15, ftol=1e-15,
                             max_nfev=20000, **kws)
        return vec(out.params), time.perf_counter() - t

    return _reweighted(fit, model, data, start, res) if ml else fit(start, np.ones(model.n_outputs))


def _stage2_problems():
    """name -> builder of a fresh (model, data, stage-1 data, certified values, sweep settings)."""
    from casest.apps.nist import read_nist

    out = {}
    scalar2 = casest.load_model_file(os.path.join(REPO, "models", "scalar2.py"))
    out["scalar2"] = lambda: (scalar2.model(), scalar2.simulate(0), None, None, None)
    pitot = casest.load_model_file(os.path.join(REPO, "models", "pitot5hole.py"))
    windows = pitot.stage_data(pitot.simulate(39001))

    def pitot_problem():
        model = pitot.model()
        stage1, stage2 = (casest.Dataset.from_arrays(model, d.signals, d.outputs) for d in windows)
        return model, stage2, stage1, None, pitot.SWEEP_SETTINGS

    out["pitot (stage-2 windows)"] = pitot_problem
    for path in sorted(glob.glob(os.path.join(REPO, "data", "nist_strd", "*.dat"))):
        for start in (1, 2):
            name = f"{os.path.basename(path)[:-4]}/{start}"
            out[name] = lambda path=path, start=start: (lambda pr: (pr.model, pr.data, None, pr.certified, None))(
                read_nist(path, start=start))
    return out


def bench_stage2(quick: bool) -> None:
    from casest.apps.baselines import concentrated_cost
    from casest.apps.nist import log_relative_error

    say("## Stage 2 against SciPy and lmfit")
    say()
    say("Every method starts from the model's nominal values (NIST: the start named after the slash) inside the "
        "same box. casest's pipeline adds its stage 1; \"casest s2\" is stage 2 alone (full mode) from the nominal "
        "values. **cold** = casest's in-process caches cleared and an empty compile cache (NLP build and every "
        "compile included; CasADi and IPOPT already loaded, as SciPy is for its peers); **warm** = the same call again on "
        "the same model and data. SciPy: `least_squares(method='trf', x_scale='jac', xtol=ftol=gtol=1e-15)`; lmfit "
        "1.3: `minimize(method='leastsq', xtol=ftol=1e-15)` (bounds through lmfit's transform); each with the model "
        "and its exact Jacobian written by hand in NumPy (`an`, `scripts/benchmarks/stage2_peers.py`, checked against casest's "
        "at the start; no CasADi call in the peers) and with finite differences of the NumPy residual (`fd`: SciPy "
        "'2-point', lmfit's default epsfcn). On the "
        "multi-channel Pitot problem every method is judged by the same criterion, the ML cost with unknown diagonal "
        "R (paper Eq. 6), and the peers also get that problem by per-channel reweighting to convergence (`ML` "
        "rows), beside their plain least squares (which minimises another criterion).")
    say()
    say("Correct = NIST: >= 6 correct digits of every certified value; otherwise within 1e-6 relative of the lowest "
        "ML cost any method found.")
    say()
    try:
        import lmfit  # noqa: F401

        have_lmfit = True
    except ImportError:
        have_lmfit = False
        say("(lmfit is not installed: `pip install lmfit` adds its columns.)")
        say()
    methods = ["pipeline", "s2", "scipy an", "scipy fd"] + (["lmfit an", "lmfit fd"] if have_lmfit else [])
    say("| problem | pipeline cold s | pipeline warm s | s2 cold s | s2 warm s | scipy an s | scipy fd s | "
        + ("lmfit an s | lmfit fd s | " if have_lmfit else "") + "correct: " + " / ".join(methods) + " |")
    say("|---|---|---|---|---|---|---|" + ("---|---|" if have_lmfit else "") + "---|")
    totals = {m: 0 for m in methods}
    warm_to_correct, cold_to_correct = [], []
    problems = _stage2_problems()
    for name, build in problems.items():
        model, data, stage1, certified, sweep_settings = build()
        start = model.nominal
        fits, times = {}, {}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for label in ("cold", "warm"):
                if label == "cold":
                    cold_state()
                t = time.perf_counter()
                est = casest.estimate(model, data, stage1_data=stage1, sweep_settings=sweep_settings)
                times[f"pipeline {label}"] = time.perf_counter() - t
            fits["pipeline"] = est.theta
            model, data, stage1, certified, sweep_settings = build()
            for label in ("cold", "warm"):
                if label == "cold":
                    cold_state()
                t = time.perf_counter()
                s2 = casest.solve_stage2(model, data, np.clip(start, model.lower_bounds, model.upper_bounds), mode="full")
                times[f"s2 {label}"] = time.perf_counter() - t
            fits["s2"] = s2.theta
            ml = model.n_outputs > 1
            for jac in ("analytic", "2-point"):
                key = "an" if jac == "analytic" else "fd"
                fits[f"scipy {key}"], times[f"scipy {key}"] = scipy_fit(model, data, start, jac, False)
                if have_lmfit:
                    fits[f"lmfit {key}"], times[f"lmfit {key}"] = _lmfit_fit(model, data, start, jac, False)
                if ml:
                    fits[f"scipy {key} ML"], times[f"scipy {key} ML"] = scipy_fit(model, data, start, jac, True)
                    if have_lmfit:
                        fits[f"lmfit {key} ML"], times[f"lmfit {key} ML"] = _lmfit_fit(model, data, start, jac, True)
        if certified is not None:
            ok = {k: bool(log_relative_error(v, certified).min() >= 6) for k, v in fits.items()}
        else:
            costs = {k: concentrated_cost(model, data, v) for k, v in fits.items()}
            best = min(costs.values())
            ok = {k: bool(c <= best + 1e-6 * max(1, abs(best))) for k, c in costs.items()}
        rows = [(name, "")] + ([(name, " ML")] if model.n_outputs > 1 else [])
        for row_name, suffix in rows:
            peer = [f"scipy an{suffix}", f"scipy fd{suffix}"] + ([f"lmfit an{suffix}", f"lmfit fd{suffix}"] if have_lmfit else [])
            if suffix:
                cells = ["-", "-", "-", "-"] + [f"{times[k]:.3f}" for k in peer]
                flags = ["-", "-"] + ["yes" if ok[k] else "NO" for k in peer]
            else:
                cells = [f"{times[k]:.3f}" for k in ("pipeline cold", "pipeline warm", "s2 cold", "s2 warm")] + [
                    f"{times[k]:.3f}" for k in peer]
                flags = ["yes" if ok[k] else "NO" for k in ["pipeline", "s2"] + peer]
            label = row_name + (" (ML by reweighting)" if suffix else (" (plain LS for the peers)" if len(rows) > 1 else ""))
            say(f"| {label} | " + " | ".join(cells) + " | " + " / ".join(flags) + " |")
        ml_suffix = " ML" if model.n_outputs > 1 else ""
        for m in methods:
            key = m if m in ("pipeline", "s2") else m + ml_suffix
            totals[m] += ok[key]
        for store, suffix in ((cold_to_correct, "cold"), (warm_to_correct, "warm")):
            entry = {"s2": times[f"s2 {suffix}"] if ok["s2"] else np.inf,
                     "pipeline": times[f"pipeline {suffix}"] if ok["pipeline"] else np.inf}
            for m in methods[2:]:
                key = m + ml_suffix
                entry[m] = times[key] if ok[key] else np.inf
            store.append(entry)
    n = len(problems)
    say()
    say(f"Correct over {n} problems (the Pitot row by the ML criterion, peers reweighted): "
        + ", ".join(f"{m} {totals[m]}/{n}" for m in methods) + ".")
    say()
    for store, label in ((cold_to_correct, "cold"), (warm_to_correct, "warm")):
        for mine in ("pipeline", "s2"):
            for other in methods[2:]:
                ours = np.array([t[mine] for t in store])
                theirs = np.array([t[other] for t in store])
                both = np.isfinite(ours) & np.isfinite(theirs)
                if not both.any():
                    continue
                say(f"- {label} casest {mine} against {other}: no later on {int(np.sum(ours <= theirs))}/{n}; on the "
                    f"{both.sum()} problems both solve, total {ours[both].sum():.3f} s against {theirs[both].sum():.3f} s, "
                    f"median ratio {np.median(ours[both] / theirs[both]):.2f}.")
    say()


# ----------------------------------------------------------------------------- scaling
def _short_period_record(n: int, seed: int):
    """A short-period record of n samples: the model file's input pattern repeated, fresh noise."""
    sp = casest.load_model_file(os.path.join(REPO, "models", "short_period.py"))
    model, exact = sp.model(), sp.model(substeps=8)
    t = np.arange(n) / sp.RATE
    u = sp.elevator(np.mod(t, sp.DURATION))
    blank = exact.dataset({"t": t, "delta_e": u, **{o: 0 * t for o in model.output_names}})
    _, clean = exact.simulate(sp.TRUTH, blank)
    z = clean + np.random.default_rng([seed, 5]).standard_normal(clean.shape) * [sp.NOISE_STD[o] for o in model.output_names]
    return sp, model, model.dataset({"t": t, "delta_e": u, **{o: z[:, j] for j, o in enumerate(model.output_names)}})


def output_error_one(n: int) -> dict:
    """Cold output-error stage 2 in this (fresh) process: build, compile, solve; then warm."""
    t0 = time.perf_counter()
    sp, model, data = _short_period_record(n, 0)
    t_data = time.perf_counter() - t0
    start = model.vector(sp.SINGLE_STAGE_START)
    t0 = time.perf_counter()
    cold = casest.solve_stage2(model, data, start, mode="full")
    t_cold = time.perf_counter() - t0
    _, _, data2 = _short_period_record(n, 1)
    t0 = time.perf_counter()
    warm = casest.solve_stage2(model, data2, start, mode="full")
    t_warm = time.perf_counter() - t0
    return {"cold": t_cold, "warm": t_warm, "data": t_data, "cold_success": bool(cold.success),
            "warm_success": bool(warm.success), "cost": float(cold.cost), "iterations": int(cold.n_iterations),
            "theta": [float(v) for v in cold.theta]}


def _scipy_output_error(sp, model, data, start):
    """The short-period output-error ML written with SciPy (the reference's time and optimum)."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import least_squares

    t, u, z = data.signals[:, 0], data.signals[:, 1], data.outputs
    V0 = sp.V0

    def simulate(theta):
        Za, Zd, Ma, Mq, Md = theta[:5]
        A = np.array([[Za, 1.0], [Ma, Mq]])
        s, out = np.zeros(12), [np.zeros(12)]  # x (2) and dx/d(Za, Zd, Ma, Mq, Md) (2 x 5)
        for i in range(t.size - 1):
            slope = (u[i + 1] - u[i]) / (t[i + 1] - t[i])

            def rhs(tt, s, i=i, slope=slope):
                de = u[i] + slope * (tt - t[i])
                x, S = s[:2], s[2:].reshape(2, 5)
                dS = A @ S
                dS[0, 0] += x[0]
                dS[0, 1] += de
                dS[1, 2] += x[0]
                dS[1, 3] += x[1]
                dS[1, 4] += de
                return np.concatenate([A @ x + np.array([Zd * de, Md * de]), dS.ravel()])

            s = solve_ivp(rhs, (t[i], t[i + 1]), s, method="DOP853", rtol=1e-10, atol=1e-12).y[:, -1]
            out.append(s)
        return np.array(out)

    def parts(theta):
        y = simulate(theta)
        x, S = y[:, :2], y[:, 2:].reshape(-1, 2, 5)
        Za, Zd, *_ = theta[:5]
        pred = np.column_stack([x[:, 0] + theta[5], x[:, 1] + theta[6], V0 * (Za * x[:, 0] + Zd * u)])
        J = np.zeros((t.size, 3, 7))
        J[:, 0, :5], J[:, 1, :5] = S[:, 0], S[:, 1]
        J[:, 0, 5], J[:, 1, 6] = 1.0, 1.0
        J[:, 2, :5] = V0 * Za * S[:, 0]
        J[:, 2, 0] += V0 * x[:, 0]
        J[:, 2, 1] += V0 * u
        return pred, J

    theta, R = np.asarray(start, dtype=float), np.var(z, axis=0)
    t0 = time.perf_counter()
    for _ in range(50):
        fit = least_squares(lambda th: ((z - parts(th)[0]) / np.sqrt(R)).ravel(), theta,
                            jac=lambda th: -(parts(th)[1] / np.sqrt(R)[None, :, None]).reshape(-1, 7),
                            bounds=(model.lower_bounds, model.upper_bounds), x_scale=model.scales,
                            xtol=1e-10, ftol=1e-10, gtol=1e-10)
        theta = fit.x
        R_new = np.mean((z - parts(theta)[0]) ** 2, axis=0)
        settled = np.all(np.abs(R_new - R) < 1e-8 * R)
        R = R_new
        if settled:
            break
    return theta, time.perf_counter() - t0


def bench_dynamic(quick: bool) -> None:
    import json
    import subprocess

    from casest.estimation.sweep.evaluators import DynamicGramEvaluator

    say("## Dynamic models")
    say()
    dc = casest.load_model_file(os.path.join(REPO, "models", "data_compatibility.py"))
    dc.WINDOW = (500.0, 600.0)  # 100 s at 50 Hz: N = 5001
    model, data = dc.model(), dc.simulate(0)
    part = casest.separate(model)
    K = 1024 if quick else 4096
    cands, _, _ = draw_candidates(model, part, casest.SweepSettings(design="sobol", n_candidates=K, seed=0))
    say(f"Stage 1 through the ODE: data compatibility (6 states, RK4), N = {data.n_samples}, {K} Sobol candidates "
        "of the six IMU biases; one simulation and Gram sum per candidate.")
    say()
    say("| evaluation | build + compile s | sweep s | candidate x sample per s |")
    say("|---|---|---|---|")
    for label, jit, threads in (("CasADi VM, 1 thread", False, 1), ("compiled, 1 thread", True, 1),
                                ("compiled, 2 threads", True, 2)):
        if not jit and not quick:
            subset = cands[: K // 8]  # the VM is slow: time an eighth of the candidates
        else:
            subset = cands
        t0 = time.perf_counter()
        ev = DynamicGramEvaluator(model, part, data, len(subset), jit=jit, threads=threads)
        t_build = time.perf_counter() - t0
        t0 = time.perf_counter()
        ev.solve(subset)
        t_sweep = time.perf_counter() - t0
        say(f"| {label} ({len(subset)} candidates) | {t_build:.2f} | {t_sweep:.2f} | "
            f"{len(subset) * data.n_samples / t_sweep:.3g} |")
    say()
    n = 2000 if quick else 10000
    cold_state()  # the subprocess inherits the empty compile cache
    out = subprocess.run([sys.executable, os.path.abspath(__file__), "--output-error-one", str(n)], capture_output=True,
                         text=True, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    sp, model_sp, data_sp = _short_period_record(n, 0)
    start = model_sp.vector(sp.SINGLE_STAGE_START)
    theta_ref, t_ref = _scipy_output_error(sp, model_sp, data_sp, start)
    prob = casest.Problem(model_sp, data_sp)
    say(f"Output-error stage 2, short-period model (2 states, 7 parameters, 3 outputs), N = {n}, from the same "
        "start (the model file's guess), R unknown (ML):")
    say()
    say("| method | seconds | ML cost (profile) | converged |")
    say("|---|---|---|---|")
    say(f"| casest cold (fresh process: build, compile, {res['iterations']} iterations) | {res['cold']:.2f} | "
        f"{prob.profile_cost(res['theta']):.10g} | {res['cold_success']} |")
    say(f"| casest warm (next record, same process) | {res['warm']:.2f} | - | {res['warm_success']} |")
    say(f"| SciPy solve_ivp + least_squares (exact sensitivities), reweighted | {t_ref:.2f} | "
        f"{prob.profile_cost(theta_ref):.10g} | - |")
    say()
    say(f"Ratios: SciPy / casest cold {t_ref / res['cold']:.1f}x, SciPy / casest warm {t_ref / res['warm']:.1f}x.")
    say()


def bench_flight_parts(quick: bool) -> None:
    """Flight-test practice on the dynamic half (scripts/benchmarks/bench_output_error.py): both output-error paths on
    the bundled dynamic files and on the 38-parameter aircraft against JAX + SciPy, and filter-error ML in
    both formulations."""
    import bench_output_error as boe

    say("## Output error and filter error (flight-test practice)")
    say()
    boe.bench_small(say)
    boe.bench_flight(skip_ipopt=quick, say=say)
    boe.bench_filter(say)


def bench_illconditioned_part(quick: bool) -> None:
    """Stage 1 on an ill-conditioned linear basis against a well-conditioned one (scripts/benchmarks/bench_illconditioned.py)."""
    import bench_illconditioned

    say("## Stage 1 on an ill-conditioned basis (60 + 3 parameters, N = 2000)")
    say()
    bench_illconditioned.bench(500 if quick else 2000, 2, lambda line: (say(f"- {line}")))
    say()


def bench_filters_part(quick: bool) -> None:
    """The EKF over a long record against filterpy and JAX (scripts/benchmarks/bench_filters.py)."""
    import bench_filters

    say("## The EKF over a record (compiled pass, filterpy, JAX)")
    say()
    bench_filters.bench(2000 if quick else 10000, 3, say)


COLD_SCRIPT = """
import json, time
t0 = time.perf_counter()
import casest
t_import = time.perf_counter() - t0
from casest.models import model_file_hooks
from casest._casadi.numerics import compile_stats
out = {"import": t_import}
module = casest.load_model_file("pitot5hole")
hooks = model_file_hooks(module)
data = module.simulate(0)
stage1, data = hooks.stage_data(data) if hooks.stage_data is not None else (None, data)

def run(model):
    before = dict(compile_stats())
    t = time.perf_counter()
    est = casest.estimate(model, data, stage1_data=stage1, sweep_settings=hooks.sweep_settings)
    after = compile_stats()
    return time.perf_counter() - t, {k: after[k] - before.get(k, 0) for k in after}, bool(est.success)

model = module.model()
out["first"] = run(model)
out["fresh_object"] = run(module.model())
out["warm"] = run(model)
est = casest.estimate(model, data, stage1_data=stage1, sweep_settings=hooks.sweep_settings)
out["stage1_point"] = [float(v) for v in est.starts[0].theta0]  # the best stage-1 candidate, SciPy's start
print(json.dumps(out))
"""

# SciPy's first fit in a fresh process: least_squares (trf, the NumPy residual and Jacobian of
# scripts/benchmarks/stage2_peers.py) reweighted per channel to the ML optimum, from casest's stage-1 point
COLD_SCIPY_SCRIPT = """
import json, sys, time
sys.path.insert(0, sys.argv[2])
import numpy as np
import casest
import bench
from casest.models import model_file_hooks
module = casest.load_model_file("pitot5hole")
hooks = model_file_hooks(module)
data = module.simulate(0)
stage1, data = hooks.stage_data(data) if hooks.stage_data is not None else (None, data)
model = module.model()
start = np.array(json.loads(sys.argv[1]))
t0 = time.perf_counter()
from scipy.optimize import least_squares  # noqa: F401
t_import = time.perf_counter() - t0
t0 = time.perf_counter()
theta, t_fit = bench.scipy_fit(model, data, start, "analytic", True)
t_call = time.perf_counter() - t0
print(json.dumps({"import": t_import, "fit": t_fit, "call": t_call}))
"""


def bench_cold(quick: bool) -> None:
    import json
    import subprocess
    import tempfile

    say("## Cold start (Pitot default: the model file's record and manoeuvre windows, `casest solve pitot5hole`)")
    say()
    say("Each row is a fresh process (`python -c`); the compile cache is a private folder, empty for the first "
        "row and as the first row left it for the second. C compiles: libraries built by the compiler / taken "
        "from the cache.")
    say()
    say("| process | import casest s | first estimate s (built / cached) | fresh model object s (built / cached) | "
        "warm estimate s | success |")
    say("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "CASEST_CACHE_DIR": cache}
        for label in ("empty cache", "filled cache"):
            out = subprocess.run([sys.executable, "-c", COLD_SCRIPT], env=env, capture_output=True, text=True,
                                 check=True, cwd=tempfile.gettempdir())
            r = json.loads(out.stdout.strip().splitlines()[-1])

            def cell(key):
                t, stats, _ = r[key]
                return f"{t:.2f} ({stats['compiled'] + stats['rebuilt']} / {stats['hit']})"

            say(f"| {label} | {r['import']:.2f} | {cell('first')} | {cell('fresh_object')} | {r['warm'][0]:.2f} | "
                f"{all(r[k][2] for k in ('first', 'fresh_object', 'warm'))} |")
        out = subprocess.run([sys.executable, "-c", COLD_SCIPY_SCRIPT, json.dumps(r["stage1_point"]),
                              os.path.dirname(os.path.abspath(__file__))], env=env, capture_output=True, text=True,
                             check=True, cwd=tempfile.gettempdir())
        peer = json.loads(out.stdout.strip().splitlines()[-1])
    say()
    say(f"SciPy in a fresh process, from casest's best stage-1 point: `import scipy.optimize` {peer['import']:.2f} s, "
        f"first `least_squares` fit (trf, NumPy Jacobian, reweighted to the ML optimum) {peer['fit']:.2f} s "
        f"({peer['call']:.2f} s with the peer's residual checks). casest's first estimate with the cache filled "
        f"(stage 1 included) / SciPy's first fit: {r['first'][0] / peer['fit']:.2f}.")
    say()


def scaling_one(N: int) -> dict:
    """Build and solve the full-mode Pitot NLP for N samples (run in a fresh process)."""
    from casest.estimation.solve.nlps import sums_nlp

    module, model, data = pitot_data(N)
    part = casest.separate(model)
    start = model.vector(module.TRUTH) * 0.9
    settings = casest.SolverSettings()
    t = time.perf_counter()
    sums_nlp(model, part, N, "full", settings)
    build = time.perf_counter() - t
    # the same build again with the compile cache now filled (in-process caches cleared)
    casest._casadi.memory.clear_memory_caches()
    t = time.perf_counter()
    sums_nlp(model, part, N, "full", settings)
    rebuild = time.perf_counter() - t
    t = time.perf_counter()
    res = casest.solve_stage2(model, data, start, part, "full", settings)
    first = time.perf_counter() - t
    # again from the same start: the steady cost of a solve once the solver's memory exists
    t = time.perf_counter()
    res = casest.solve_stage2(model, data, start, part, "full", settings)
    solve = time.perf_counter() - t
    # VmHWM: this process's peak resident memory (ru_maxrss would include the parent's
    # peak, which survives fork and exec)
    with open("/proc/self/status") as status:
        hwm = next((int(line.split()[1]) for line in status if line.startswith("VmHWM")), 0)
    return {"N": N, "build": build, "rebuild": rebuild, "first": first, "solve": solve, "iterations": res.n_iterations, "success": res.success,
            "jit": settings.resolved_jit(N), "threads": settings.resolved_threads(N), "rss_mib": hwm / 1024}


def bench_scaling(quick: bool) -> None:
    import json
    import subprocess

    say("## Stage 2: time per IPOPT iteration against N (Pitot model, full mode)")
    say()
    say("Each N in a fresh process with an empty compile cache (peak RSS is that process's, data included); "
        "`SolverSettings()` defaults. "
        "Build: the NLP and its compiled sums; cached: the same build again in the same process with its "
        "in-process caches cleared and the compile cache filled. First solve: includes allocating the solver's work memory. "
        "Solve: the same solve again (whole `solve_stage2` call: start checks, IPOPT, cost at the end); "
        "s / iteration = solve / iterations.")
    say()
    say("| N | build s | build cached s | first solve s | solve s | iterations | s / iteration | JIT | threads | "
        "peak RSS MiB |")
    say("|---|---|---|---|---|---|---|---|---|---|")
    sizes = [100, 1000, 10000, 100000] + ([] if quick else [1000000])
    rows = []
    for N in sizes:
        cold_state()  # each N compiles into an empty cache: the build column includes its compiles
        out = subprocess.run([sys.executable, os.path.abspath(__file__), "--scaling-one", str(N)],
                             capture_output=True, text=True, check=True)
        row = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append(row)
        per_iter = row["solve"] / max(row["iterations"], 1)
        say(f"| {N} | {row['build']:.2f} | {row['rebuild']:.2f} | {row['first']:.2f} | {row['solve']:.2f} | {row['iterations']} | {per_iter:.4f} | "
            f"{'yes' if row['jit'] else 'no'} | {row['threads']} | {row['rss_mib']:.0f} |")
    n = np.array([r["N"] for r in rows], dtype=float)
    per = np.array([r["solve"] / max(r["iterations"], 1) for r in rows])
    big = n >= 10000
    slope = np.polyfit(np.log(n[big]), np.log(per[big]), 1)[0] if big.sum() >= 2 else float("nan")
    say()
    say(f"Log-log slope of time per iteration against N (N >= 1e4, same JIT/thread settings): {slope:.3f}.")
    say()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parts", nargs="+", default=["cold", "stage1", "stage2", "dynamic", "flight", "filters",
                                                       "scaling", "illcond"],
                        choices=["cold", "stage1", "stage2", "dynamic", "flight", "filters", "scaling", "illcond"])
    parser.add_argument("--quick", action="store_true", help="skip the largest sizes")
    parser.add_argument("--out", help="also write the report (Markdown) here")
    parser.add_argument("--keep-cache", action="store_true",
                        help="use the user's compile cache (default: an empty one, so builds include compiles)")
    parser.add_argument("--scaling-one", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--output-error-one", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.output_error_one:
        import json

        print(json.dumps(output_error_one(args.output_error_one)))
        return 0
    if args.scaling_one:
        import json

        print(json.dumps(scaling_one(args.scaling_one)))
        return 0
    if not args.keep_cache:
        cold_state()  # every build below compiles as on a fresh machine, unless a part says otherwise
    say(f"# casest benchmarks ({time.strftime('%Y-%m-%d')})")
    say()
    say(f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"NumPy {np.__version__}, CasADi {ca.__version__}. Command: `python3 scripts/benchmarks/bench.py "
        + " ".join(argv if argv is not None else sys.argv[1:]) + "`")
    say()
    for part in args.parts:
        {"cold": bench_cold, "stage1": bench_stage1, "stage2": bench_stage2, "dynamic": bench_dynamic,
         "flight": bench_flight_parts, "filters": bench_filters_part, "scaling": bench_scaling,
         "illcond": bench_illconditioned_part}[part](args.quick)
    if args.out:
        from casest.data import atomic_write_text

        # the hand-written reading of the figures (from its heading on) is kept
        kept = ""
        if os.path.exists(args.out):
            with open(args.out, encoding="utf-8") as fh:
                old = fh.read()
            if READING in old:
                kept = "\n" + old[old.index(READING):]
        atomic_write_text(args.out, "\n".join(LINES) + "\n" + kept)
    return 0


if __name__ == "__main__":
    sys.exit(main())
