#!/usr/bin/env python3
"""What bounds stage 1's arithmetic rate: a roofline of the Pitot sweep on this machine.

    python3 scripts/benchmarks/stage1_roofline.py [--n 10000] [--candidates 5000] [--figure docs/figures/stage1_roofline.png]

Counts, per candidate-sample, the operations of the compiled per-sample function the sweep
sums (the Gram entries with the model's algebra fused in, after the features that depend on
the data only are hoisted), and the bytes it reads: from the data block (shared by the
candidates of a SIMD group, 8 with AVX-512, else 4; the block stays in cache across the groups)
and from main memory (a block read once per call of up to 4096 candidates). Measures on this
machine the dense matrix product's rate (both cores: the compute roof; and one core's, the
sweep's one-thread rate set against it), NumPy's copy bandwidth on 512 MiB (the
memory roof), the sweep's rate (1 and 2 threads), the same sums with the trigonometric
functions replaced by a multiplication (their share), the least-squares products alone on stored
rows ``[A, y]`` (as ``bench.py --parts stage1`` reports them) and NumPy's ``M'M`` of one
candidate's rows. Prints a table and draws the roofline (matplotlib) if ``--figure`` is given.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import casadi as ca
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from bench_common import pitot_data  # noqa: E402
from stage1_kernels import blas_rate, gram_kernel, time_lanes, same_shape_rate  # noqa: E402

import casest  # noqa: E402
from casest.backend.lane_sums import LaneSum  # noqa: E402
from casest.two_stage.sweep.candidates import draw_candidates  # noqa: E402
from casest.two_stage.sweep.evaluators import GramEvaluator, SAMPLE_BLOCK, evaluate_candidates  # noqa: E402

ARITHMETIC = {ca.OP_ADD, ca.OP_SUB, ca.OP_MUL, ca.OP_DIV, ca.OP_SQ, ca.OP_NEG, ca.OP_TWICE, ca.OP_INV}
TRIG = {ca.OP_SIN, ca.OP_COS}


def copy_bandwidth() -> float:
    """GB/s of NumPy copying 512 MiB (bytes read plus written), best of 3."""
    a = np.ones(2**26)
    b = np.empty_like(a)
    best = np.inf
    for _ in range(3):
        t = time.perf_counter()
        np.copyto(b, a)
        best = min(best, time.perf_counter() - t)
    return 2 * a.nbytes / best / 1e9


def cache_bandwidth() -> float:
    """GB/s of BLAS ``ddot`` on two 512 KiB vectors (in the core's cache), one thread, best of 5."""
    a, b = np.ones(2**16), np.ones(2**16)
    reps, best = 2000, np.inf
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(reps):
            a @ b
        best = min(best, (time.perf_counter() - t) / reps)
    return 2 * a.nbytes / best / 1e9


def op_counts(fun: ca.Function) -> dict:
    """Arithmetic operations (the outputs' accumulation included), trigonometric calls, inputs."""
    ids = [fun.instruction_id(k) for k in range(fun.n_instructions())]
    return {"arithmetic": sum(i in ARITHMETIC for i in ids) + fun.nnz_out(0), "trig": sum(i in TRIG for i in ids),
            "data_values": sum(fun.nnz_in(k) for k in range(3))}


_BUILD = {ca.OP_ADD: lambda a, b: a + b, ca.OP_SUB: lambda a, b: a - b, ca.OP_MUL: lambda a, b: a * b,
          ca.OP_DIV: lambda a, b: a / b, ca.OP_SQ: lambda a: a * a, ca.OP_NEG: lambda a: -a,
          ca.OP_TWICE: lambda a: a + a, ca.OP_INV: lambda a: 1 / a, ca.OP_ASSIGN: lambda a: a,
          ca.OP_SIN: lambda a: 0.5 * a, ca.OP_COS: lambda a: 0.5 * a}


def without_trig(fun: ca.Function) -> ca.Function:
    """``fun`` rebuilt from its instruction list with sin(x) and cos(x) replaced by 0.5 x (one
    multiplication each): the same sums without the trigonometric calls, for their share."""
    inputs = fun.sx_in()
    work, out = {}, [None] * fun.nnz_out(0)
    for k in range(fun.n_instructions()):
        op, ins, outs = fun.instruction_id(k), fun.instruction_input(k), fun.instruction_output(k)
        if op == ca.OP_INPUT:
            work[outs[0]] = inputs[ins[0]][ins[1]]
        elif op == ca.OP_OUTPUT:
            out[outs[1]] = work[ins[0]]
        elif op == ca.OP_CONST:
            work[outs[0]] = ca.SX(fun.instruction_constant(k))
        else:
            args = [work[i] for i in ins if i >= 0][: 1 if op in (ca.OP_SQ, ca.OP_NEG, ca.OP_TWICE, ca.OP_INV,
                                                                    ca.OP_ASSIGN, ca.OP_SIN, ca.OP_COS) else 2]
            work[outs[0]] = _BUILD[op](*args)
    return ca.Function(fun.name() + "_notrig", inputs, [ca.vertcat(*out)])


def sweep_time(evaluator, outputs, cands) -> float:
    """Seconds of the whole evaluation of the candidates, best of 3."""
    best = np.inf
    for _ in range(3):
        t = time.perf_counter()
        evaluate_candidates(evaluator, outputs, cands)
        best = min(best, time.perf_counter() - t)
    return best


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=10000)
    parser.add_argument("--candidates", type=int, default=5000)
    parser.add_argument("--figure", help="write the roofline figure here (PNG)")
    args = parser.parse_args(argv)
    roofline(args.n, args.candidates, args.figure)
    return 0


def roofline(N: int, K: int, figure: str | None = None, say=print) -> None:
    """Measure and print (through ``say``) the roofline table of the Pitot sweep; draw it to ``figure``."""
    module, model, data = pitot_data(N)
    part = casest.separate(model)
    cands, _, _ = draw_candidates(model, part, casest.SweepSettings(design="random", n_candidates=K, seed=1))
    evaluators = {t: GramEvaluator(part, data, K, jit=True, threads=t) for t in (1, 2)}
    per_sample = evaluators[1]._program.per_sample
    counts = op_counts(per_sample)
    ls_flops = 2 * len(evaluators[1]._varying)
    data_bytes = 8 * counts["data_values"]
    chunk = evaluators[1].chunk
    peak, core_peak, bandwidth, cache = blas_rate(), blas_rate(threads=1), copy_bandwidth(), cache_bandwidth()
    rates = {t: N * K / sweep_time(evaluators[t], data.outputs, cands) for t in (1, 2)}
    # the same sums without the trigonometric calls, one thread: their share of the time
    sample_data = evaluators[1]._sample_data(0, min(N, SAMPLE_BLOCK))
    lanes_full = LaneSum.build(per_sample, sample_data, "roofline_full")
    lanes_cut = LaneSum.build(without_trig(per_sample), sample_data, "roofline_notrig")
    width = lanes_full.lanes
    values = np.hstack([cands[:64], evaluators[1]._program.candidate_constants(cands[:64])])
    t_full = min(_timed(lambda: lanes_full(values)) for _ in range(5))
    t_cut = min(_timed(lambda: lanes_cut(values)) for _ in range(5))
    # the least-squares products alone on stored rows [A, y] (per candidate: nothing shared)
    ls_kernel, _ = gram_kernel(evaluators[1], cands[0], N, model.n_outputs, part.n_linear, True)
    t_ls = min(time_lanes(ls_kernel, max(5, int(2e7 // (N * ls_flops))), 1) for _ in range(3))
    rows_bytes = 8 * model.n_outputs * (part.n_linear + 1)
    blas_ls = same_shape_rate(N, model.n_outputs, part.n_linear + 1)
    flops = counts["arithmetic"]
    say(f"Pitot sweep, N = {N}, K = {K}; per candidate-sample: {flops} arithmetic operations ({ls_flops} of them "
          f"the least-squares products and sums), {counts['trig']} sin/cos, {counts['data_values']} data values "
          f"({data_bytes} B) read per SIMD group of {width} candidates from a block of {SAMPLE_BLOCK} samples "
          f"({SAMPLE_BLOCK * data_bytes / 2**20:.1f} MiB, in cache across the groups of a call).")
    say()
    say("| quantity | value |")
    say("|---|---|")
    say(f"| dense matrix product, both cores (compute roof) | {peak:.1f} GFLOP/s |")
    say(f"| NumPy copy of 512 MiB (memory roof) | {bandwidth:.1f} GB/s |")
    say(f"| BLAS ddot of two 512 KiB vectors, 1 thread (cache roof) | {cache:.1f} GB/s |")
    say(f"| dense matrix product, one core | {core_peak:.1f} GFLOP/s |")
    say(f"| bytes per candidate-sample from the block (cache) | {data_bytes / width:.0f} |")
    say(f"| bytes per candidate-sample from main memory (a block per call of {chunk} candidates) | "
          f"{data_bytes / chunk:.3f} |")
    for t in (1, 2):
        say(f"| sweep, {t} thread(s): candidate-samples/s | {rates[t]:.3g} |")
        say(f"| sweep, {t} thread(s): all arithmetic GFLOP/s (% of the compute roof) | {flops * rates[t] / 1e9:.1f} "
              f"({100 * flops * rates[t] / 1e9 / peak:.0f}%) |")
        say(f"| sweep, {t} thread(s): least-squares GFLOP/s (% of the compute roof) | {ls_flops * rates[t] / 1e9:.1f} "
              f"({100 * ls_flops * rates[t] / 1e9 / peak:.0f}%) |")
    say(f"| sweep, 1 thread: all arithmetic, % of one core's matrix-product rate | "
        f"{100 * flops * rates[1] / 1e9 / core_peak:.0f}% |")
    trig_share = 1 - t_cut / t_full
    say(f"| share of the sums' time in sin/cos (1 thread) | {100 * trig_share:.0f}% |")
    say(f"| sweep, 1 thread, all arithmetic without the sin/cos time (% of one core's matrix-product rate) | "
        f"{flops * rates[1] / 1e9 / (1 - trig_share):.1f} ({100 * flops * rates[1] / 1e9 / (1 - trig_share) / core_peak:.0f}%) |")
    say(f"| sweep, 2 threads, all arithmetic without the sin/cos time (% of the compute roof) | "
          f"{flops * rates[2] / 1e9 / (1 - trig_share):.1f} ({100 * flops * rates[2] / 1e9 / (1 - trig_share) / peak:.0f}%) |")
    say(f"| least-squares products alone on stored rows, 1 thread: GFLOP/s ({rows_bytes} B a sample and candidate) | "
          f"{ls_flops * N / t_ls / 1e9:.1f} |")
    say(f"| NumPy M'M of one candidate's rows: GFLOP/s | {blas_ls:.1f} |")
    if figure:
        _figure(figure, peak, bandwidth, cache, flops * rates[2] / 1e9 / (1 - trig_share), [
            ("sweep (fused), 2 threads: all arithmetic", flops / (data_bytes / chunk), flops * rates[2] / 1e9),
            ("sweep (fused), 2 threads: least squares", ls_flops / (data_bytes / chunk), ls_flops * rates[2] / 1e9),
            ("sweep arithmetic vs. its cache traffic", flops / (data_bytes / width), flops * rates[2] / 1e9),
            ("LS products on stored rows, 1 thread", ls_flops / rows_bytes, ls_flops * N / t_ls / 1e9),
            ("NumPy M'M of one candidate's rows", (part.n_linear + 2) / 16, blas_ls)])


def _timed(fun) -> float:
    t = time.perf_counter()
    fun()
    return time.perf_counter() - t


def _figure(path: str, peak: float, bandwidth: float, cache: float, without_trig_rate: float, points: list) -> None:
    """The roofline (log-log): the memory and cache roofs up to the compute roof, the sweep's
    rate with its sin/cos time removed, and the measured points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.logspace(-2, 4, 200)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.loglog(x, np.minimum(peak, bandwidth * x), "k-", label=f"roof: memory {bandwidth:.0f} GB/s, {peak:.0f} GFLOP/s")
    ax.loglog(x, np.minimum(peak, cache * x), "k--", label=f"roof: cache, 1 thread, {cache:.0f} GB/s")
    ax.axhline(without_trig_rate, color="tab:blue", ls=":",
               label=f"sweep without its sin/cos time: {without_trig_rate:.0f} GFLOP/s")
    for (name, intensity, rate), marker, color in zip(points, "osD^v", ["tab:blue", "tab:orange", "tab:green",
                                                                       "tab:red", "tab:purple"]):
        ax.loglog([intensity], [rate], marker, color=color, markersize=8, label=f"{name}: {rate:.1f} GFLOP/s")
    ax.set_xlabel("arithmetic intensity (operations per byte)")
    ax.set_ylabel("GFLOP/s")
    ax.set_title("Stage 1 (Pitot sweep) on this machine")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    sys.exit(main())
