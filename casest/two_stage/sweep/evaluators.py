"""Evaluators of A(xi2) and b(xi2) over the data for many candidates at once: the Gram sums per
channel (static models, compiled) and the bulk evaluation with the QR fallback; their
dynamic-model counterparts are in :mod:`casest.two_stage.sweep.dynamic_evaluators`."""

from __future__ import annotations

import threading

import casadi as ca
import numpy as np

from ..._casadi.sample_blocks import evaluate_samples
from ...data.dataset import Dataset
from ...problem.separate import Partition
from ...backend.array_sums import ArraySum, ArrayValues
from ...backend.lane_sums import LaneSum, LaneValues
from .gram_program import GramProgram, per_sample_A_and_b
from ...backend.least_squares import batched_least_squares, condition_below, feasible_solutions, refined_least_squares


__all__ = ["BulkEvaluator", "GramEvaluator", "evaluate_candidates", "evaluate_all_candidates", "evaluate_candidates_qr"]


#: samples summed at once by the compiled Gram sums: their copy of the data and the features that
#: depend on the data only exist for one block (about 2 MB for the Pitot model)
SAMPLE_BLOCK = 8192
#: the blocks' data kept between calls at most (a fixed amount, whatever N): a record whose data
#: exceed it has the further blocks' features recomputed at each call
BLOCK_CACHE_BYTES = 48 * 2**20

#: candidate-samples (times channels) a Gram pass must hold per thread before its candidates are
#: split over threads: handing a part to a pool thread and collecting it costs 0.1-0.2 ms here, so
#: smaller passes (a small problem's sweep, the refinements of a few candidates) ran 1.1-3.7x slower
#: on two threads than on one (NIST Thurber, Eckerle4, Rat42, Gauss1 at 64-4096 candidates)
THREAD_MIN_WORK = 1.5e5

_POOLS: dict = {}
_POOLS_LOCK = threading.Lock()


def shared_pool(threads: int):
    """The process's thread pool of ``threads`` workers (created once: starting threads for every
    sweep cost 1-3 ms, as much as a small sweep's evaluation). Its tasks never submit to it."""
    with _POOLS_LOCK:
        if threads not in _POOLS:
            from concurrent.futures import ThreadPoolExecutor

            _POOLS[threads] = ThreadPoolExecutor(threads, thread_name_prefix="casest_sweep")
        return _POOLS[threads]


# ----------------------------------------------------------------------------- evaluation
class BulkEvaluator:
    """Evaluates A and b for chunks of xi2 candidates over all samples.

    One CasADi function maps the per-sample A and b over the N samples and a fixed
    chunk of candidates; it is built once and called through
    its buffer interface, which reads and writes NumPy arrays in place. A short last
    chunk is padded with copies of its last candidate.
    """

    def __init__(self, partition: Partition, data: Dataset, memory_mb: float, n_candidates: int, jit: bool = False):
        self.n_samples = N = data.n_samples
        self.n_outputs = ny = data.outputs.shape[1]
        # rows of outputs not measured weigh 0; each channel's R divides by its own count
        self.mask = data.output_mask().reshape(-1)
        self.counts = data.observed_counts()
        self.n1 = n1 = partition.n_linear
        self.n2 = n2 = partition.n_nonlinear
        ns = data.signals.shape[1]
        # bytes per candidate: A and b buffers, their reordered copies and the QR work arrays
        per_candidate = 8 * N * ny * (4 * max(n1, 1) + 3)
        self.chunk = int(max(1, min(n_candidates, memory_mb * 2**20 // per_candidate)))
        self.partition, self.signals = partition, data.signals
        self._lanes = self._lane_values(partition, data, jit)
        if self._lanes is not None:
            return
        X = ca.MX.sym("X", ns, N)
        xi2 = ca.MX.sym("xi2", n2)
        A_all = partition.A.map(N)(X, xi2) if n1 else ca.MX(ny, 0)
        b_all = partition.b.map(N)(X, xi2)
        per_candidate_fn = ca.Function("Ab_all", [X, xi2], [A_all, b_all])
        mapped = (
            per_candidate_fn.map("Ab_chunk", "serial", self.chunk, [0], [])
            if self.chunk > 1
            else per_candidate_fn
        )
        if jit:
            from ..._casadi.numerics import compile_function

            mapped = compile_function(mapped, ("-O2",))
        self._buffer, self._eval = mapped.buffer()
        self._signals = np.ascontiguousarray(data.signals).reshape(-1)  # column-major X
        self._xi2 = np.zeros(n2 * self.chunk)
        self._A = np.zeros(ny * n1 * N * self.chunk)
        self._b = np.zeros(ny * N * self.chunk)
        self._buffer.set_arg(0, memoryview(self._signals))
        self._buffer.set_arg(1, memoryview(self._xi2))
        self._buffer.set_res(0, memoryview(self._A))
        self._buffer.set_res(1, memoryview(self._b))

    @staticmethod
    def _lane_values(partition: Partition, data: Dataset, jit: bool):
        """A and b at every sample: compiled SIMD C, a candidate per lane, or (not ``jit``)
        NumPy operations over candidates x samples; None where an operation has no such form."""
        key = ("bulk", data.signals.shape[1], data.outputs.shape[1])
        per_sample, program = partition.builds.get_or_build(key, lambda: per_sample_A_and_b(partition, *key[1:]))
        if per_sample is None:
            return None
        return LaneValues.build(per_sample, [data.signals], "bulk_lanes") if jit else (
            ArrayValues.build(per_sample, [data.signals], program) if program else None)

    @property
    def uncompiled_arrays(self) -> bool:
        """Whether A and b come from NumPy operations over candidates x samples (nothing compiled)."""
        return isinstance(self._lanes, ArrayValues)

    def __call__(self, xi2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A of shape (M, N*n_outputs, n1) and b of shape (M, N*n_outputs), M <= chunk."""
        M = xi2.shape[0]
        if M > self.chunk:
            raise ValueError(f"at most {self.chunk} candidates per call, got {M}")
        N, ny, n1 = self.n_samples, self.n_outputs, self.n1
        if self._lanes is not None:  # per sample: vec(A) column-major (entry j + ny*i), then b
            values = self._lanes(xi2)
            A = values[:, :, : ny * n1].reshape(M, N, n1, ny).transpose(0, 1, 3, 2).reshape(M, N * ny, n1)
            return A, values[:, :, ny * n1:].reshape(M, N * ny)
        padded = np.empty((self.chunk, self.n2))
        padded[:M] = xi2
        padded[M:] = xi2[-1] if M else 0.0
        self._xi2[:] = padded.reshape(-1)  # column-major n2 x chunk
        self._eval()
        # flat index of A: j + ny*(i + n1*(k + N*m)) for output j, xi1 component i, sample k
        # a copy: with one output the reshape is a view of the buffer the next call overwrites
        A = self._A.reshape(self.chunk, N, n1, ny)[:M].transpose(0, 1, 3, 2).reshape(M, N * ny, n1).copy()
        b = self._b.reshape(self.chunk, N * ny)[:M].copy()
        return A, b


class GramEvaluator:
    """Per-channel Gram matrices ``sum_k [A_k y_k]' [A_k y_k]`` for chunks of candidates.

    ``y = z - b(xi2)``. The Gram entries are summed over samples in one compiled pass, so A
    and b never reach memory: with ``jit`` a candidate per SIMD lane (8 or 4 a vector)
    (:class:`~casest.backend.lane_sums.LaneSum`), else (or for a function with an operation
    with no vector form) CasADi's map-reduce, one candidate per pass. Per candidate the sweep
    returns (n1+1)(n1+2)/2 numbers per channel. Sub-expressions that
    depend only on the data (``x``, ``z``) are computed once for all candidates, those
    that depend only on xi2 once per candidate (``casadi.extract_parametric``). The
    least squares then take the normal equations of the column-scaled Gram matrix;
    candidates where that loses accuracy (scaled condition number above ``condition_limit``,
    or a residual below 1e-8 of ``y'y`` where the subtraction cancels) are re-solved by
    column-scaled QR on A itself (:class:`BulkEvaluator`, compiled when the Gram sums are). Entries that are constant per
    sample are N times that constant and stay out of the loop; ``threads`` threads take
    contiguous parts of the candidates, each with its own buffer. A record longer than
    ``SAMPLE_BLOCK`` samples is summed block by block: the compiled sums' copy of the data and
    the hoisted features are kept for at most ``BLOCK_CACHE_BYTES`` of blocks and recomputed at
    each call beyond, so the memory above the record does not grow with N. Without ``jit``,
    ``cached`` takes the compiled sums where their library is already at hand (compiled by an
    earlier sweep of the same structure, in this or an earlier session: the compile cache),
    compiling nothing: :class:`SweepSettings` ``jit=None`` below its threshold asks for that.
    """

    def __init__(self, partition: Partition, data: Dataset, n_candidates: int, jit: bool = False, threads: int = 1,
                 max_chunk: int = 4096, condition_limit: float = 1e10, cached: bool = False):
        # n_candidates only sizes the chunks of candidates handled per call
        from ...backend.sums import map_sum

        self.partition, self.data = partition, data
        self.jit, self.condition_limit = jit, float(condition_limit)
        self.n_samples = N = data.n_samples
        self.n_outputs = ny = data.outputs.shape[1]
        self.n1 = partition.n_linear
        self.n2 = partition.n_nonlinear
        self.chunk = int(max(1, min(n_candidates, max_chunk)))
        # with missing outputs the data are [z; mask] per sample: a product counts only where measured
        self.masked = data.has_missing
        self.counts = data.observed_counts()
        key = ("gram", data.signals.shape[1], ny, self.masked)
        program = partition.builds.get_or_build(key, lambda: GramProgram(partition, *key[1:]))
        self._rows, self._cols = program.rows, program.cols
        self._varying, self._fixed, self._fixed_sum = program.varying, program.fixed, N * program.fixed_per_sample
        self._program = program
        self.threads = max(1, int(threads))
        # compiled: a candidate per SIMD lane (lane_sums), block by block of samples; where
        # the function has an operation with no vector (or NumPy) form, CasADi's map-reduce
        blocks = [(a, min(a + SAMPLE_BLOCK, N)) for a in range(0, N, SAMPLE_BLOCK)] or [(0, N)]
        sample_data = self._sample_data(*blocks[0])
        # below the compile threshold the compiled sums only where their library is already at hand
        # (an earlier sweep of this model's structure compiled it); else NumPy operations over
        # candidates x samples (no compile)
        self._lanes = (LaneSum.build(program.per_sample, sample_data, "gram_lanes", cached_only=not jit)
                       if jit or cached else None)
        self.blocks = blocks if jit or self._lanes is not None else [(0, N)]
        if self._lanes is None and not jit:
            if len(blocks) > 1:  # the NumPy sums take the whole record at once
                sample_data = self._sample_data(0, N)
            self._lanes = program.array_sum(sample_data)
        if self._lanes is None:  # the map-reduce reads the whole record's columns in place
            self.blocks = [(0, N)]
            sample_data = self._sample_data(0, N)
            signals, outputs, per_sample_features = sample_data
            self._signals = np.ascontiguousarray(signals).reshape(-1)
            self._outputs = np.ascontiguousarray(outputs).reshape(-1)
            self._features = np.ascontiguousarray(per_sample_features).reshape(-1)
            # -O3 -march=native: the compiled loop runs on the machine that compiles it
            self._summed = map_sum(program.per_sample, N, 1, "gram_sum", jit, ("-O3", "-march=native"), n_data=3)
            # one buffer (own work memory, own candidate and result arrays) per thread; CasADi
            # releases the GIL while a compiled pass runs, so threads over candidates scale
            self._workers = [self._worker(program.n_constants) for _ in range(self.threads)]
        self._pool = None
        self._bulk = None
        self.n_fallback = 0
        self._kept_blocks, self._kept_bytes = {}, 0

    def _block_lanes(self, b: int, start: int, stop: int):
        """The compiled sums over block ``b``: kept while the kept blocks' data stay within
        ``BLOCK_CACHE_BYTES``, built again at each call beyond (the features recomputed)."""
        if b == 0:
            return self._lanes
        if b in self._kept_blocks:
            return self._kept_blocks[b]
        lanes = self._lanes.on(self._sample_data(start, stop))
        if self._kept_bytes + lanes.nbytes <= BLOCK_CACHE_BYTES:
            self._kept_blocks[b] = lanes
            self._kept_bytes += lanes.nbytes
        return lanes

    def _sample_data(self, start: int, stop: int) -> list:
        """The compiled sums' per-sample inputs for samples ``start:stop``: signals, outputs (with
        a mask: ``[z; m]``) and the features that depend on the data only."""
        data = self.data
        signals = data.signals[start:stop]
        outputs = data.outputs[start:stop]
        if self.masked:  # as Dataset.filled_outputs and Dataset.output_mask give them, for this block
            seen = data.observed[start:stop]
            outputs = np.hstack([np.where(seen, outputs, 0.0), seen.astype(float)])
        (features,) = evaluate_samples(self._program.features, [signals, outputs])  # (L, n_f)
        return [signals, outputs, features]

    def _worker(self, n_constants: int) -> tuple:
        xi2, c, G = np.zeros(self.n2), np.zeros(n_constants), np.zeros(max(len(self._varying), 1))
        buffer, run = self._summed.buffer()
        for k, arr in enumerate((self._signals, self._outputs, self._features, xi2, c)):
            buffer.set_arg(k, memoryview(arr))
        buffer.set_res(0, memoryview(G))
        return buffer, run, xi2, c, G

    def _passes(self, worker: int, xi2: np.ndarray, consts: np.ndarray, out: np.ndarray) -> None:
        """One compiled pass over the data per candidate; the Python loop costs ~2 us each."""
        _, run, x_buf, c_buf, G = self._workers[worker]
        for m in range(xi2.shape[0]):
            x_buf[:] = xi2[m]
            c_buf[:] = consts[m]
            run()
            out[m] = G

    def _lane_passes(self, values: np.ndarray, parts: list, out: np.ndarray) -> None:
        """The SIMD (or array) sums for contiguous parts of the candidates, one thread each, block
        by block of samples."""
        for b, (start, stop) in enumerate(self.blocks):
            lanes = self._block_lanes(b, start, stop)
            if len(parts) <= 1:
                block_sums = [lanes(values)]
            else:
                futures = [self._thread_pool().submit(lanes, values[p]) for p in parts]
                block_sums = [future.result() for future in futures]
            for p, sums in zip(parts, block_sums):
                out[p] = sums if b == 0 else out[p] + sums

    def _thread_pool(self):
        if self._pool is None:
            self._pool = shared_pool(self.threads)
        return self._pool

    def gram(self, xi2: np.ndarray) -> np.ndarray:
        """Gram matrices, shape (M, n_outputs, n1+1, n1+1), for M candidates (rows of xi2)."""
        M = xi2.shape[0]
        T, ny = len(self._rows), self.n_outputs
        consts = self._program.candidate_constants(xi2)
        flat = np.empty((M, T * ny))
        flat[:, self._fixed] = self._fixed_sum
        varying = np.empty((M, max(len(self._varying), 1)))
        threads = min(self.threads, max(1, int(M * self.n_samples * self.n_outputs // THREAD_MIN_WORK)))
        if isinstance(self._lanes, ArraySum):  # a thread per block of candidates at most: smaller parts cost more
            threads = min(threads, self._lanes.blocks(M))
        parts = [p for p in np.array_split(np.arange(M), threads) if len(p)]
        if self._lanes is not None:
            self._lane_passes(np.hstack([xi2, consts]), parts, varying)
        elif len(parts) <= 1:
            self._passes(0, xi2, consts, varying)
        else:
            # contiguous parts: each thread writes its rows of ``varying`` in place
            futures = [self._thread_pool().submit(self._passes, w, xi2[p], consts[p], varying[p[0] : p[-1] + 1])
                       for w, p in enumerate(parts)]
            for future in futures:
                future.result()
        flat[:, self._varying] = varying[:, : len(self._varying)]
        return self._matrices(flat)

    def _matrices(self, flat: np.ndarray) -> np.ndarray:
        """Symmetric Gram matrices (M, n_outputs, n1+1, n1+1) from their upper triangles (M, n_outputs * T)."""
        M, n = flat.shape[0], self.n1 + 1
        flat = flat.reshape(M, self.n_outputs, len(self._rows))
        G = np.zeros((M, self.n_outputs, n, n))
        G[:, :, self._rows, self._cols] = flat
        G[:, :, self._cols, self._rows] = flat
        return G

    @property
    def bulk(self) -> "BulkEvaluator":
        """A and b themselves (for the QR fallback and diagnostics), built on first use."""
        if self._bulk is None:
            self._bulk = BulkEvaluator(self.partition, self.data, 64.0, 4096, jit=self.jit)
        return self._bulk

    def solve(self, cands: np.ndarray, lb: np.ndarray | None = None, ub: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """xi1 (M, n1), R (M, n_outputs) and a full-rank mask (M,) for M candidates.

        With bounds ``lb, ub`` (shape (n1,)) xi1 is the best feasible one: candidates
        whose unconstrained xi1 leaves the box are re-solved as box-constrained least
        squares on the same Gram matrices (:func:`box_least_squares`).
        """
        M, n1 = cands.shape[0], self.n1
        xi1 = np.full((M, n1), np.nan)
        R = np.full((M, self.n_outputs), np.nan)
        ok = np.zeros(M, dtype=bool)
        redo = np.zeros(M, dtype=bool)
        normal, scales = [], []  # the scaled normal matrices and column norms of the candidates to redo only
        for start in range(0, M, self.chunk):
            stop = min(M, start + self.chunk)
            G = self.gram(cands[start:stop])
            # a candidate where the model is NaN or infinite at some sample is not a fit
            finite = np.isfinite(G).reshape(stop - start, -1).all(axis=1)
            G = np.where(finite[:, None, None, None], G, 0.0)
            AtA, Aty, yty = G[:, :, :n1, :n1], G[:, :, :n1, n1], G[:, :, n1, n1]
            if n1 == 0:
                R[start:stop] = np.where(finite[:, None], yty / self.counts, np.nan)
                ok[start:stop] = finite
                xi1[start:stop] = np.zeros((stop - start, 0))
                continue
            P, q = AtA.sum(axis=1), Aty.sum(axis=1)
            d = np.sqrt(np.maximum(np.diagonal(P, axis1=1, axis2=2), 0.0))
            safe = np.where(d > 0, d, 1.0)
            Ps = P / (safe[:, :, None] * safe[:, None, :])
            well = finite & (d > 0).all(axis=1)
            well[well] = condition_below(Ps[well], self.condition_limit)
            x = np.zeros((stop - start, n1))
            if well.any():
                x[well] = np.linalg.solve(Ps[well], (q / safe)[well][..., None])[..., 0] / safe[well]
            # per-channel residual sum of squares: y'y - 2 x'A'y + x'A'A x
            rss = yty - 2 * np.einsum("mjn,mn->mj", Aty, x) + np.einsum("mn,mjnk,mk->mj", x, AtA, x)
            accurate = well & np.all(rss > 1e-8 * yty, axis=1)
            x, rss = feasible_solutions(AtA, Aty, yty, x, rss, accurate, lb, ub)
            xi1[start:stop][accurate] = x[accurate]
            R[start:stop][accurate] = rss[accurate] / self.counts
            ok[start:stop] = accurate
            # a column of A that is zero at every sample is rank-deficient on A itself too: no re-solve
            again = ~accurate & finite & (d > 0).all(axis=1)
            redo[start:stop] = again
            normal.append(Ps[again])
            scales.append(safe[again])
        if redo.any():
            idx = np.flatnonzero(redo)
            self.n_fallback += len(idx)
            xi1[idx], R[idx], ok[idx] = evaluate_candidates_qr(self.bulk, self.data.outputs, cands[idx], lb, ub,
                                                               normal=(np.concatenate(normal), np.concatenate(scales)))
        return xi1, R, ok


def evaluate_candidates(evaluator, Z: np.ndarray, cands: np.ndarray, lb: np.ndarray | None = None,
              ub: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """xi1 (M, n1), R (M, n_outputs) and a full-rank mask (M,) for all candidates.

    ``lb, ub`` (shape (n1,)): the bounds of xi1; each candidate then gets its best
    feasible xi1.
    """
    if isinstance(evaluator, GramEvaluator):
        return evaluator.solve(cands, lb, ub)
    return evaluate_candidates_qr(evaluator, Z, cands, lb, ub)


#: candidate-samples of a sweep above which a progress bar shows (about a few seconds here)
PROGRESS_WORK = 5e7
#: candidate-samples per update of the bar
PROGRESS_BLOCK_WORK = 2e8
#: the fewest candidates per update of the bar
PROGRESS_MIN_BLOCK = 128


def evaluate_all_candidates(evaluator, Z, cands, bounds, progress: bool, block: int = 4096):
    """:func:`evaluate_candidates` for all candidates, with a tqdm progress bar on large sweeps
    (many candidates, or a long record: the bar moves in blocks of about ``PROGRESS_BLOCK_WORK``
    candidate-samples, at least ``PROGRESS_MIN_BLOCK`` and at most ``block`` candidates)."""
    bar = None
    n_samples = max(int(np.shape(Z)[0]), 1)
    # at least 128 candidates a block: fewer make more passes over the record (20: 1.7 times slower)
    block = int(max(min(PROGRESS_MIN_BLOCK, block), min(block, PROGRESS_BLOCK_WORK // n_samples)))
    if progress and len(cands) > 1 and len(cands) * n_samples > PROGRESS_WORK:
        try:
            from tqdm import tqdm

            bar = tqdm(total=len(cands), unit="cand", desc="stage 1", leave=False)
        except ImportError:  # tqdm is optional (extra "parallel")
            bar = None
    if bar is None:
        return evaluate_candidates(evaluator, Z, cands, *bounds)
    parts = []
    try:
        for start in range(0, len(cands), block):
            parts.append(evaluate_candidates(evaluator, Z, cands[start:start + block], *bounds))
            bar.update(min(block, len(cands) - start))
    finally:
        bar.close()
    return tuple(np.concatenate([p[k] for p in parts]) for k in range(3))


def evaluate_candidates_qr(evaluator: BulkEvaluator, Z: np.ndarray, cands: np.ndarray, lb: np.ndarray | None = None,
                 ub: np.ndarray | None = None, normal: tuple | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """As :func:`evaluate_candidates`, on A and b themselves: by column-scaled QR, or, given the
    candidates' column-scaled normal matrices and column norms ``normal`` (shapes (M, n1, n1)
    and (M, n1), from the Gram sums), by conjugate gradients on A preconditioned by them
    (:func:`refined_least_squares`; column-scaled QR where they do not settle)."""
    M = cands.shape[0]
    N, ny, n1 = evaluator.n_samples, evaluator.n_outputs, evaluator.n1
    chunk = evaluator.chunk
    xi1 = np.empty((M, n1))
    R = np.empty((M, ny))
    ok = np.empty(M, dtype=bool)
    z = np.nan_to_num(Z).reshape(-1)  # sample-major, channel-minor: matches the A, b rows
    mask = evaluator.mask
    gaps = not np.all(mask == 1.0)  # without missing outputs, no copy of A to multiply by ones
    for start in range(0, M, chunk):
        stop = min(M, start + chunk)
        A, b = evaluator(cands[start:stop])
        y = (z[None, :] - b) * mask
        if gaps:
            A = A * mask[None, :, None]
        if normal is not None and n1:
            x, full = refined_least_squares(A, y, normal[0][start:stop], normal[1][start:stop])
            if not full.all():
                x[~full], full[~full] = batched_least_squares(A[~full], y[~full], without_q=True)
        else:
            x, full = batched_least_squares(A, y, without_q=True)
        if lb is not None and n1 and np.any(full & np.any((x < lb) | (x > ub), axis=1)):
            Ac, yc = A.reshape(stop - start, N, ny, n1), y.reshape(stop - start, N, ny)
            AtA = np.einsum("mkji,mkjl->mjil", Ac, Ac)
            Aty = np.einsum("mkji,mkj->mji", Ac, yc)
            x, _ = feasible_solutions(AtA, Aty, np.einsum("mkj,mkj->mj", yc, yc), np.nan_to_num(x), np.zeros((stop - start, ny)),
                             full, lb, ub)
            x[~full] = np.nan
        resid = y - np.einsum("mkn,mn->mk", A, np.nan_to_num(x)) if n1 else y
        xi1[start:stop] = x
        R[start:stop] = np.sum(resid.reshape(stop - start, N, ny) ** 2, axis=1) / evaluator.counts
        ok[start:stop] = full & np.isfinite(R[start:stop]).all(axis=1)
    R[~ok] = np.nan
    return xi1, R, ok
