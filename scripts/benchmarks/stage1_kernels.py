"""Stage 1's kernels and timing helpers, shared by bench_stage1.py and stage1_roofline.py: the
machine's BLAS rate, one Gram kernel of the Pitot sweep, and how long a compiled lane kernel
takes."""

from __future__ import annotations

import time

import casadi as ca
import numpy as np

from casest.backend.array_sums import ArraySum


def blas_rate(threads: int | None = None) -> float:
    """GFLOP/s of a dense matrix product on this machine (best of 3), on all cores or, with
    ``threads``, with BLAS limited to that many threads (threadpoolctl)."""
    from contextlib import nullcontext

    a = np.random.default_rng(0).standard_normal((2000, 2000))
    best = np.inf
    if threads is None:
        limit = nullcontext()
    else:
        from threadpoolctl import threadpool_limits

        limit = threadpool_limits(limits=threads, user_api="blas")
    with limit:
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
    if evaluator._lanes is not None:  # the sweep's SIMD sums: the same products, a candidate per lane
        from casest.backend.lane_sums import LaneSum

        lanes = LaneSum.build(per_sample, [rows], "gram_rows_lanes")
        return lanes, None
    kernel = map_sum(per_sample, N, 1, "gram_rows_sum", jit, ("-O3", "-march=native"), n_data=2)
    args = [np.ascontiguousarray(rows).reshape(-1), np.zeros(N)]
    return kernel, args


def time_lanes(lanes, reps: int, threads: int = 1) -> float:
    """Seconds per candidate of the SIMD (or NumPy array) sums when ``threads`` threads call them
    concurrently: one SIMD group of candidates a call, a block of them for the array sums."""
    from concurrent.futures import ThreadPoolExecutor

    per_call = lanes.block if isinstance(lanes, ArraySum) else lanes.lanes
    reps = max(1, reps * 4 // per_call)
    values = np.zeros((per_call, 1))
    with ThreadPoolExecutor(threads) as pool:
        t = time.perf_counter()
        list(pool.map(lambda _: [lanes(values) for _ in range(reps)], range(threads)))
        return (time.perf_counter() - t) / (per_call * reps)


def time_buffer(fun, args, reps: int, threads: int = 1) -> float:
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
