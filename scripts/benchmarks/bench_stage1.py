"""Stage 1 of scripts/benchmarks/bench.py: throughput, the BLAS share, the peers, the bound-aware ranking."""

from __future__ import annotations

import os
import time

import numpy as np

from bench_common import REPO, pitot_data, say

import casest  # noqa: E402
from casest.two_stage.sweep import draw_candidates
from casest.two_stage.sweep.evaluators import GramEvaluator, evaluate_candidates
from stage1_kernels import time_buffer, blas_rate, gram_kernel, same_shape_rate, time_lanes  # noqa: E402


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
        "LS GFLOP/s (% of GEMM peak) | same-shape BLAS GFLOP/s (LS %) | LS share of sweep (upper bound) | QR fallbacks |")
    say("|---|---|---|---|---|---|---|---|---|---|---|")
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
        t = time.perf_counter()
        ev = GramEvaluator(part, data, K, jit=jit, threads=threads)
        build = time.perf_counter() - t
        t = time.perf_counter()
        evaluate_candidates(ev, data.outputs, cands)
        sweep_s = time.perf_counter() - t
        # least-squares part: the sweep's Gram-product code (same SX products, same compiled
        # map-reduce, same threads) run alone on one candidate's [A, y], plus the small solves
        n1, ny = part.n_linear, model.n_outputs
        ls_kernel, ls_args = gram_kernel(ev, cands[0], N, ny, n1, jit)
        n_products = len(ev._varying)
        reps = max(5, int(2e7 // (N * n_products)))
        if ls_args is None:
            t_kernel = min(time_lanes(ls_kernel, reps, threads) for _ in range(3))
        else:
            t_kernel = min(time_buffer(ls_kernel, ls_args, reps, threads) for _ in range(3))
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
            f"{100 * share:.0f}% | {ev.n_fallback} |")
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
    bench_stage1_memory(quick)
    bench_stage1_roofline()
    bench_stage1_peers(quick)
    bench_bounded_ranking()


def bench_stage1_roofline() -> None:
    """What bounds the sweep's arithmetic rate (scripts/benchmarks/stage1_roofline.py), with its figure."""
    import stage1_roofline

    say("### What bounds stage 1's rate: a roofline")
    say()
    stage1_roofline.roofline(10000, 5000, os.path.join(REPO, "docs", "figures", "stage1_roofline.png"), say)
    say()
    say("![roofline](figures/stage1_roofline.png)")
    say()


def bench_stage1_memory(quick: bool) -> None:
    """Process peak memory (RSS) of a whole sweep against N, each N in fresh processes."""
    import stage1_memory

    say("### Stage 1's memory")
    say()
    say("`casest.sweep` with 500 random candidates on Pitot records of N samples, each in fresh processes "
        "(`scripts/benchmarks/stage1_memory.py`): the process's peak resident memory (Linux `VmHWM`, reset once the "
        "record is loaded) above its resident memory before the record was loaded (after `import casest` and the "
        "model), and above the loaded record. *first*: the process's first sweep, its imports, builds and compiled "
        "libraries included; *later*: a process that ran a small sweep (2000 samples, 8 candidates) first, so the "
        "peak is the sweep's own working memory.")
    say()
    stage1_memory.table([10000, 100000] if quick else [10000, 100000, 1000000], 500,
                        os.path.dirname(os.path.abspath(__file__)), say)
    say()


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
