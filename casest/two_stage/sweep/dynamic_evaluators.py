"""Stage-1 evaluators of a dynamic model: A(xi2) and b(xi2) through the states simulated per
candidate, as Gram sums carried along the recursion or over the whole record (delayed outputs)."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ...data.dataset import Dataset
from ...models.dynamic import DynamicModel
from ...problem.separate import Partition
from .evaluators import GramEvaluator
from .gram_program import channel_gram, split_constant_entries


__all__ = ["DynamicGramEvaluator", "DynamicBulkEvaluator"]


class DynamicGramEvaluator(GramEvaluator):
    """Per-channel Gram matrices of a dynamic model: the states are simulated per candidate.

    xi1 enters neither the rhs nor the initial state, so each xi2 candidate fixes the state
    trajectory. One CasADi function of xi2 runs the time recursion once (``fold`` of a step
    that advances the state and adds the sample's Gram entries of ``[A_k y_k]``), so the
    trajectory never reaches memory; compiled to C when ``jit``. Entries constant per sample
    stay out of the loop, and the per-step data (interpolated inputs, step lengths, outputs)
    are prepared once for all candidates. Threads take contiguous parts of the candidates,
    each with its own buffer.
    """

    def __init__(self, model: DynamicModel, partition: Partition, data: Dataset, n_candidates: int,
                 jit: bool = False, threads: int = 1, max_chunk: int = 4096,
                 condition_limit: float = 1e10):
        from ..._casadi.numerics import compile_function

        self.model, self.partition, self.data = model, partition, data
        self.jit, self.condition_limit = jit, float(condition_limit)
        self.n_samples = N = data.n_samples
        self.n_outputs = ny = data.outputs.shape[1]
        self.n1 = n1 = partition.n_linear
        self.n2 = n2 = partition.n_nonlinear
        self.chunk = int(max(1, min(n_candidates, max_chunk)))
        self.masked = data.has_missing
        self.counts = data.observed_counts()
        ns = partition.A.size1_in(0)
        s, xi2 = ca.SX.sym("s", ns), ca.SX.sym("xi2", n2)
        z = ca.SX.sym("z", 2 * ny if self.masked else ny)
        self._rows, self._cols = np.triu_indices(n1 + 1)
        gram, self._varying, self._fixed, fixed_per_sample = split_constant_entries(
            channel_gram(partition, s, z, xi2, self.masked))
        self._fixed_sum = N * fixed_per_sample
        per_sample = ca.Function("dyn_gram_i", [s, z, xi2], [gram])
        nx, nu, nz, nv = model.n_states, len(model.inputs), z.numel(), gram.numel()
        step = model.step_function
        # one pass of the time recursion carries [x; Gram sums; xi2]: the trajectory never
        # reaches memory, and the per-step data (interval inputs, step, u_k, z_k) are the
        # same for every candidate, prepared once here
        Sym = ca.SX if step.is_a("SXFunction") else ca.MX
        nuk = step.size1_in(1)
        acc, d = Sym.sym("acc", nx + nv + n2), Sym.sym("d", 2 * nuk + 1 + nu + nz)
        x, sums, xi = acc[:nx], acc[nx:nx + nv], acc[nx + nv:]
        theta = partition.assemble_symbolic(Sym.zeros(n1), xi)
        theta_rhs = ca.vertcat(*[theta[i] for i in model.rhs_parameter_index]) if model.rhs_parameter_index else Sym(0, 1)
        # vertsplit, not slicing: an empty slice of a column is a 1 x 0 row (a model without inputs)
        _, u_k, z_k = ca.vertsplit(d, [0, 2 * nuk + 1, 2 * nuk + 1 + nu, d.numel()])
        x_next = step(x, d[:nuk], d[nuk:2 * nuk], d[2 * nuk], theta_rhs)
        advance = ca.Function("dyn_gram_step", [acc, d],
                              [ca.vertcat(x_next, sums + per_sample(ca.vertcat(x, u_k), z_k, xi), xi)])
        xi2_m, d0 = ca.MX.sym("xi2", n2), ca.MX.sym("x0_data", len(model.initial_from_data))
        D, last = ca.MX.sym("d", d.numel(), max(N - 1, 1)), ca.MX.sym("last", nu + nz)
        x0 = model.initial_function(partition.assemble_symbolic(ca.MX.zeros(n1), xi2_m), d0)
        if N > 1:
            final = advance.fold(N - 1)(ca.vertcat(x0, ca.MX.zeros(nv), xi2_m), D)
            x_end, total = final[:nx], final[nx:nx + nv]
        else:
            x_end, total = x0, ca.MX.zeros(nv)
        u_last, z_last = ca.vertsplit(last, [0, nu, nu + nz])
        G = total + per_sample(ca.vertcat(x_end, u_last), z_last, xi2_m)
        fn = ca.Function("dyn_gram", [xi2_m, D, last, d0], [G])
        self._summed = compile_function(fn, ("-O3", "-march=native")) if jit else fn
        outputs = np.hstack([data.filled_outputs(), data.output_mask()]) if self.masked else data.outputs
        if N > 1:
            Ua, Ub = model.interval_input_values(data.signals[:, 1:])
            per_step = np.vstack([Ua.T, Ub.T, np.diff(data.signals[:, 0])[None, :], data.signals[:-1, 1:].T,
                                  outputs[:-1].T])
        else:
            per_step = np.zeros((d.numel(), 1))
        # column-major (n x N-1) per-step data: the transpose of a C-ordered array, read flat
        self._args = [np.ascontiguousarray(per_step.T).reshape(-1),
                      np.concatenate([data.signals[-1, 1:], outputs[-1]]),
                      np.ascontiguousarray(model.initial_values(data), dtype=float)]
        self.threads = max(1, int(threads))
        self._workers = [self._dyn_worker() for _ in range(self.threads)]
        self._pool = None
        self._bulk = None
        self.n_fallback = 0

    def _dyn_worker(self) -> tuple:
        xi2, G = np.zeros(self.n2), np.zeros(self._summed.nnz_out(0))
        buffer, run = self._summed.buffer()
        for k, arr in enumerate([xi2] + self._args):
            buffer.set_arg(k, memoryview(arr))
        buffer.set_res(0, memoryview(G))
        return buffer, run, xi2, G

    def _dyn_passes(self, worker: int, xi2: np.ndarray, out: np.ndarray) -> None:
        _, run, x_buf, G = self._workers[worker]
        for m in range(xi2.shape[0]):
            x_buf[:] = xi2[m]
            run()
            out[m] = G

    def gram(self, xi2: np.ndarray) -> np.ndarray:
        """Gram matrices, shape (M, n_outputs, n1+1, n1+1), for M candidates (rows of xi2)."""
        M = xi2.shape[0]
        T, ny = len(self._rows), self.n_outputs
        flat = np.empty((M, T * ny))
        flat[:, self._fixed] = self._fixed_sum
        varying = np.empty((M, self._summed.nnz_out(0)))
        parts = [p for p in np.array_split(np.arange(M), min(self.threads, max(M, 1))) if len(p)]
        if len(parts) <= 1:
            self._dyn_passes(0, xi2, varying)
        else:
            futures = [self._thread_pool().submit(self._dyn_passes, w, xi2[p], varying[p[0]: p[-1] + 1])
                       for w, p in enumerate(parts)]
            for future in futures:
                future.result()
        flat[:, self._varying] = varying[:, : len(self._varying)]
        return self._matrices(flat)

    @property
    def bulk(self) -> "DynamicBulkEvaluator":
        if self._bulk is None:
            self._bulk = DynamicBulkEvaluator(self.model, self.partition, self.data)
        return self._bulk


class DynamicBulkEvaluator:
    """A and b of a dynamic model over the whole record, for a block of candidates per call
    (the QR fallback, diagnostics, and the sweep of delayed outputs, which mix samples).

    The per-candidate function (simulation, A and b per sample, the output delays' kernel) is
    mapped over ``chunk`` candidates and compiled to C when ``jit``: one call evaluates a block.
    """

    def __init__(self, model: DynamicModel, partition: Partition, data: Dataset, jit: bool = False,
                 n_candidates: int = 1, memory_mb: float = 64.0):
        from ..._casadi.numerics import compile_function

        self.n_samples = N = data.n_samples
        self.n_outputs = ny = data.outputs.shape[1]
        self.mask = data.output_mask().reshape(-1)
        self.counts = data.observed_counts()
        self.n1, self.n2 = partition.n_linear, partition.n_nonlinear
        per_candidate = 8.0 * N * ny * (self.n1 + 1) * 3  # A and b, with the copies the solve makes
        self.chunk = int(max(1, min(n_candidates, 64, memory_mb * 2**20 // per_candidate)))
        xi2 = ca.MX.sym("xi2", self.n2)
        T, U = ca.MX.sym("t", 1, N), ca.MX.sym("u", len(model.inputs), N)
        d0 = ca.MX.sym("x0_data", len(model.initial_from_data))
        theta = partition.assemble_symbolic(ca.MX.zeros(self.n1), xi2)
        X = model.trajectory_symbols(theta, d0, T, U)
        S = ca.vertcat(X, U)
        A_all = partition.A.map(N)(S, xi2) if self.n1 else ca.MX(ny, 0)
        b_all = partition.b.map(N)(S, xi2)
        if model.output_delays:  # A and b of delayed outputs: the same delay on every column of A
            b_all = model.delayed_outputs(b_all, theta)
            if self.n1:  # (ny, n1 N) sample-major blocks -> rows l * ny + c of an (n1 ny, N) array
                A_all = ca.reshape(model.output_delays.apply(ca.reshape(A_all, ny * self.n1, N), theta,
                                                             model.parameter_names, self.n1), ny, self.n1 * N)
        # without xi1, b alone (an empty output would reach the generated C as a null copy)
        single = ca.Function("dyn_Ab", [xi2, T, U, d0], [b_all, A_all] if self.n1 else [b_all])
        # the record's arguments are shared by the block's candidates (not repeated)
        block = single.map("dyn_Ab_block", "serial", self.chunk, [1, 2, 3], []) if self.chunk > 1 else single
        self._fn = compile_function(block, ("-O3", "-march=native")) if jit else block
        args = [np.ascontiguousarray(data.signals[:, 0]), np.ascontiguousarray(data.signals[:, 1:]),
                np.ascontiguousarray(model.initial_values(data), dtype=float)]  # (N, nu) C order = (nu, N) F order
        self._xi2 = np.zeros((self.chunk, self.n2))  # C order (K, n2) = the (n2, K) argument in F order
        self._A = np.zeros(self.chunk * N * self.n1 * ny)
        self._b = np.zeros(self.chunk * N * ny)
        self._buffer, self._run = self._fn.buffer()
        for k, arr in enumerate([self._xi2] + args):
            self._buffer.set_arg(k, memoryview(arr.reshape(-1)))
        self._args = args  # kept alive: the buffer points into them
        self._buffer.set_res(0, memoryview(self._b))
        if self.n1:
            self._buffer.set_res(1, memoryview(self._A))

    def __call__(self, xi2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A of shape (M, N*n_outputs, n1) and b of shape (M, N*n_outputs)."""
        N, ny, n1, K = self.n_samples, self.n_outputs, self.n1, self.chunk
        rows = np.atleast_2d(xi2)
        As, bs = [], []
        for start in range(0, rows.shape[0], K):
            part = rows[start:start + K]
            m = part.shape[0]
            self._xi2[:m] = part
            self._xi2[m:] = part[-1]
            self._run()
            # outputs column-major: A (ny, K n1 N) flat is [m][k][l][c], b (ny, K N) flat is [m][k][c];
            # rows of the result are sample-major and channel-minor
            As.append(self._A.reshape(K, N, n1, ny)[:m].transpose(0, 1, 3, 2).reshape(m, N * ny, n1))
            bs.append(self._b.reshape(K, N * ny)[:m].copy())
        return np.concatenate(As), np.concatenate(bs)
