"""Stage 1: the residual-sampling sweep over xi2 (paper Sec. II.C, Eq. 17-19).

For every candidate xi2 the linear parameters follow from an unweighted linear least
squares problem ``min || Z - A(xi2) xi1 - B(xi2) ||`` (R = I, as in the paper's
Step 3), and the residuals give ``R(xi2)`` (per-channel mean square) and ``Tr[R]``.
The landscape of ``Tr[R]`` tells whether there is one clear minimum.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Sequence

import casadi as ca
import numpy as np

from .errors import IdentifiabilityError
from .data import Dataset
from .dynamic import DynamicModel
from .model import Model, ModelError, OptionError
from .measurement import measurement_of
from .problem import Problem
from .separate import Partition

__all__ = [
    "SweepSettings",
    "Landscape",
    "IdentifiabilityError",
    "sweep",
    "draw_candidates",
    "VERDICTS",
]

#: Verdicts of the sweep and what each one means.
VERDICTS = {
    "linear": "xi2 is empty: stage 1 is one linear least squares",
    "unique": "one clear minimum of Tr[R]; the linearisation (Eq. 17) and curvature (Eq. 18) checks hold",
    "multiple": "separate basins with statistically equivalent fits",
    "flat": "the curvature check (Eq. 18) fails: xi2 poorly determined around the best candidate",
    "coarse": "the linearisation check (Eq. 17) fails even after local refinement: the sweep is too coarse",
}



@dataclass(frozen=True)
class SweepSettings:
    """Settings of the stage-1 sweep.

    Attributes
    ----------
    design : {"auto", "grid", "sobol", "random"}
        How xi2 candidates are drawn from the parameters' priors (truncated to their
        bounds). ``grid`` takes prior quantiles on a tensor grid; ``sobol`` a scrambled
        Sobol sequence; ``random`` independent draws. ``auto`` is a grid for up to two
        swept parameters and Sobol above.
    n_candidates : int
        Target number of candidates (a grid takes the largest full grid not above it).
    seed : int
        Seed of the Sobol scrambling and random draws.
    linearization_tol : float
        tau_1 of Eq. 17: largest accepted relative change of the prediction over half a
        sweep step.
    curvature_tol : float
        tau_2 of Eq. 18: smallest accepted eigenvalue of the normalised profile
        Gauss-Newton matrix in xi2.
    flat_spread : float
        Absolute flatness test (works for any number of swept parameters): the landscape
        is ``flat`` when the one-sigma interval of the worst-determined combination of xi2
        (profile Fisher information with R of the best candidate) spans more than this
        fraction of the swept prior mass (prior-CDF units).
    max_refinements : int
        When Eq. 17 fails at the best candidate, the sweep is refined around it (a local
        grid of half the step, ``3**n2`` points for up to four swept parameters, the
        ``2 n2`` axis neighbours above) up to this many times, until Eq. 17 holds; the
        verdict is ``coarse`` only if it still fails.
    confidence : float
        Level of the likelihood-ratio tests that decide whether another local minimum
        fits as well as the best one and whether a ridge separates them.
    memory_mb : float
        Memory budget for one chunk of candidates in ``method="qr"`` (A, b and the QR
        work arrays).
    method : {"gram", "qr"}
        ``gram`` (default): per-channel Gram matrices of [A, z - b] summed over samples
        inside one CasADi map-reduce (A and b never stored), normal equations of the
        column-scaled Gram matrix, and column-scaled QR for the candidates where those
        would lose accuracy. ``qr``: A and b for chunks of candidates into memory and
        batched QR for every candidate (the reference; 3-10x slower).
    jit : bool or None
        Compile the loops over samples to C (gcc or cc; 0.2-1 s the first time a model
        structure is swept, then taken from the compile cache). ``None`` (default): compile
        when N x candidates >= ``jit_min_work`` and a compiler is on the PATH.
    jit_min_work : float
        N x candidates from which ``jit=None`` compiles. Measured on the Pitot sweep: the
        VM evaluates 3.6e6 candidate x samples per second, compiled code 2.5e7; a compile
        costs 0.25 s (0.03 s from the cache), so compiling pays from about 1e6 (empty
        cache) or 1.3e5 (cached); 2e5 loses at most 0.2 s once per model structure.
    threads : int or None
        Threads over candidates (``method="gram"``; each runs its own compiled pass over
        the data); ``None``: one per core, with at least 16 candidates each.
        Monte-Carlo workers pass 1.
    criterion : {"trace", "likelihood"}
        What ranks the candidates: ``trace`` (default), Tr[R] as in the paper; with one
        channel the two agree. ``likelihood``: the profile ML cost sum_j N_j/2 ln R_j, which
        does not depend on the channels' units; use it when the channels are in different
        units (m/s and rad, say), where Tr[R] is dominated by the channel with the largest
        numbers. Tr[R] is recorded either way.
    """

    design: str = "auto"
    n_candidates: int = 2000
    seed: int = 0
    linearization_tol: float = 0.05
    curvature_tol: float = 1e-8
    flat_spread: float = 0.25
    max_refinements: int = 10
    confidence: float = 0.99
    memory_mb: float = 256.0
    method: str = "gram"
    jit: bool | None = None
    jit_min_work: float = 2e5
    threads: int | None = None
    criterion: str = "trace"

    def resolved_jit(self, n_samples: int, n_candidates: int) -> bool:
        """Whether the sweep's loops are compiled (see ``jit``)."""
        if self.jit is None:
            from .numerics import compiler_available

            return n_samples * n_candidates >= self.jit_min_work and compiler_available()
        return bool(self.jit)

    def resolved_threads(self, n_candidates: int) -> int:
        """Threads over candidates (see ``threads``)."""
        from .numerics import available_cores

        if self.threads is None:
            return int(max(1, min(available_cores(), n_candidates // 16)))
        return max(1, int(self.threads))

    def __post_init__(self):
        if self.method not in ("gram", "qr"):
            raise OptionError(f"SweepSettings.method must be 'gram' or 'qr', got {self.method!r}")
        if self.design not in ("auto", "grid", "sobol", "random"):
            raise OptionError(
                f"SweepSettings.design must be 'auto', 'grid', 'sobol' or 'random', got {self.design!r}"
            )
        if self.n_candidates < 1:
            raise OptionError("SweepSettings.n_candidates must be >= 1")
        if self.criterion not in ("trace", "likelihood"):
            raise OptionError(f"SweepSettings.criterion must be 'trace' or 'likelihood', got {self.criterion!r}")


@dataclass
class Landscape:
    """What the stage-1 sweep found.

    Attributes
    ----------
    nonlinear : tuple of str
        Names of xi2 (columns of ``candidates``).
    linear : tuple of str
        Names of xi1 (columns of ``xi1``).
    output_names : tuple of str
        Channels (columns of ``R``).
    candidates : ndarray, shape (M, n2)
        Swept xi2 values, physical units.
    xi1 : ndarray, shape (M, n1)
        Least-squares xi1 at each candidate (NaN where A was rank-deficient).
    R : ndarray, shape (M, n_outputs)
        Per-channel residual mean square at each candidate.
    trace_R : ndarray, shape (M,)
        ``Tr[R(xi2)]`` (paper Eq. 19); ``inf`` where A was rank-deficient.
    best_index : int
        Candidate with the smallest ranking value (``Tr[R]`` by default).
    local_minima : ndarray of int
        Candidates that are local minima of the ranking among their neighbours, best first.
    competing : ndarray of int
        Local minima in a separate basin that fit statistically as well as the best.
    verdict : str
        One of :data:`VERDICTS`.
    reason : str
        The verdict's reason in words.
    recommended_mode : str
        The stage-2 mode ``casest.estimate(mode="auto")`` uses: ``"reduced"`` when there
        are linear and nonlinear parameters, else ``"full"`` (a failed or climbing solve is
        repeated in the other mode).
    design : str
        The design actually used.
    grid_shape : tuple of int or None
        Grid dimensions when ``design == "grid"``.
    linearization_ratio : float or None
        Left-hand side of Eq. 17 at the best candidate.
    curvature_min_eig : float or None
        Smallest eigenvalue of the normalised profile Gauss-Newton matrix (Eq. 18).
    n_samples : int
        N of the data swept.
    seconds : float
        Wall time of the sweep.
    nominal_xi1, nominal_R : ndarray or None
        Least-squares xi1 and R at the parameters' nominal xi2 (evaluated beside the
        design; ``None`` when nothing is swept).
    n_design : int or None
        The first ``n_design`` candidates are the design (``grid_shape`` applies to them);
        the rest were added by local refinement around the best candidate. ``None``: all.
    flat_spread : float or None
        One-sigma interval of the worst-determined xi2 combination, in prior-CDF units
        (the absolute flatness test).
    criterion : str
        What ranked the candidates (:attr:`SweepSettings.criterion`).
    ranking : ndarray, shape (M,) or None
        The ranked values (``Tr[R]``, or the profile ML cost for ``"likelihood"``).
    """

    nonlinear: tuple
    linear: tuple
    output_names: tuple
    candidates: np.ndarray
    xi1: np.ndarray
    R: np.ndarray
    trace_R: np.ndarray
    best_index: int
    local_minima: np.ndarray
    competing: np.ndarray
    verdict: str
    reason: str
    recommended_mode: str
    design: str
    grid_shape: tuple | None
    linearization_ratio: float | None
    curvature_min_eig: float | None
    n_samples: int
    seconds: float = 0.0
    nominal_xi1: np.ndarray | None = None
    nominal_R: np.ndarray | None = None
    n_design: int | None = None
    flat_spread: float | None = None
    criterion: str = "trace"
    ranking: np.ndarray | None = None

    def __post_init__(self):
        if self.ranking is None:
            self.ranking = self.trace_R

    @property
    def best_xi2(self) -> np.ndarray:
        """xi2 of the best candidate, shape (n2,)."""
        return self.candidates[self.best_index].copy()

    @property
    def best_xi1(self) -> np.ndarray:
        """xi1 of the best candidate, shape (n1,)."""
        return self.xi1[self.best_index].copy()

    @property
    def best_R(self) -> np.ndarray:
        """R of the best candidate, shape (n_outputs,)."""
        return self.R[self.best_index].copy()

    def summary(self) -> str:
        """A few lines for the report."""
        lines = [
            f"verdict: {self.verdict}",
            f"reason: {self.reason}",
            f"design: {self.design}, {len(self.trace_R)} candidates, N = {self.n_samples}",
        ]
        if self.nonlinear:
            best = ", ".join(f"{n} = {v:.6g}" for n, v in zip(self.nonlinear, self.best_xi2))
            ranked = "" if self.criterion == "trace" else f"; profile ML cost {self.ranking[self.best_index]:.10g}"
            lines.append(f"best candidate: {best}; Tr[R] = {self.trace_R[self.best_index]:.6g}{ranked}")
            lines.append(
                f"local minima: {len(self.local_minima)}, competing: {len(self.competing)}"
            )
        if self.linearization_ratio is not None:
            lines.append(f"linearisation check (paper Eq. 17): half a sweep step changes the prediction by "
                         f"{self.linearization_ratio:.3g} of its norm")
        if self.curvature_min_eig is not None:
            lines.append(f"curvature check (paper Eq. 18): smallest normalised eigenvalue {self.curvature_min_eig:.3g}")
        if self.flat_spread is not None:
            lines.append(f"worst-determined xi2 combination: 1-sigma spans {self.flat_spread:.3g} of the swept prior mass")
        if self.n_design is not None and self.n_design < len(self.trace_R):
            lines.append(f"refined: {len(self.trace_R) - self.n_design} candidates added around the best")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """Plain-Python form for JSON (arrays as nested lists; inf/NaN as strings)."""
        from .numerics import encode_array

        out = {}
        for key, value in self.__dict__.items():
            if isinstance(value, np.ndarray):
                out[key] = encode_array(value)
            elif isinstance(value, tuple):
                out[key] = list(value)
            else:
                out[key] = value
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "Landscape":
        from .numerics import decode_array

        kw = dict(data)
        for key in ("candidates", "xi1", "R", "trace_R"):
            kw[key] = decode_array(kw[key], float)
        for key in ("nominal_xi1", "nominal_R", "ranking"):
            if kw.get(key) is not None:
                kw[key] = decode_array(kw[key], float)
        for key in ("local_minima", "competing"):
            kw[key] = decode_array(kw[key], int)
        for key in ("nonlinear", "linear", "output_names"):
            kw[key] = tuple(kw[key])
        if kw.get("grid_shape") is not None:
            kw["grid_shape"] = tuple(kw["grid_shape"])
        return cls(**kw)


# ----------------------------------------------------------------------------- design
def draw_candidates(
    model: Model, partition: Partition, settings: SweepSettings = SweepSettings()
) -> tuple[np.ndarray, str, tuple | None]:
    """Draw xi2 candidates from the parameters' priors, truncated to their bounds.

    Returns
    -------
    candidates : ndarray, shape (M, n2)
    design : str
        The design used (``auto`` resolved).
    grid_shape : tuple of int or None
    """
    params = [model.parameters[i] for i in partition.nonlinear_index]
    n2 = len(params)
    if n2 == 0:
        return np.zeros((1, 0)), "none", None
    design = settings.design
    if design == "auto":
        design = "grid" if n2 <= 2 else "sobol"
    if design == "grid":
        per_dim = max(2, int(math.floor(settings.n_candidates ** (1.0 / n2) + 1e-9)))
        axes = []
        for p in params:
            prior = p.sampling_prior
            if prior.finite_support(p.lb, p.ub):
                u = np.linspace(0.0, 1.0, per_dim)
            else:
                u = (np.arange(per_dim) + 0.5) / per_dim
            axes.append(prior.ppf(u, p.lb, p.ub))
        mesh = np.meshgrid(*axes, indexing="ij")
        cands = np.column_stack([m.reshape(-1) for m in mesh])
        return cands, "grid", tuple([per_dim] * n2)
    if design == "sobol":
        m = max(1, int(math.ceil(math.log2(settings.n_candidates))))
        from scipy.stats import qmc

        u = qmc.Sobol(d=n2, scramble=True, seed=settings.seed).random_base2(m)
        u = u[: settings.n_candidates]
    else:
        u = np.random.default_rng(settings.seed).random((settings.n_candidates, n2))
    cands = np.column_stack([p.sampling_prior.ppf(u[:, j], p.lb, p.ub) for j, p in enumerate(params)])
    return cands, design, None


# ----------------------------------------------------------------------------- evaluation
class _BulkEvaluator:
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
            from .numerics import compile_function

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

    def __call__(self, xi2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A of shape (M, N*n_outputs, n1) and b of shape (M, N*n_outputs), M <= chunk."""
        M = xi2.shape[0]
        if M > self.chunk:
            raise ValueError(f"at most {self.chunk} candidates per call, got {M}")
        padded = np.empty((self.chunk, self.n2))
        padded[:M] = xi2
        padded[M:] = xi2[-1] if M else 0.0
        self._xi2[:] = padded.reshape(-1)  # column-major n2 x chunk
        self._eval()
        N, ny, n1 = self.n_samples, self.n_outputs, self.n1
        # flat index of A: j + ny*(i + n1*(k + N*m)) for output j, xi1 component i, sample k
        A = self._A.reshape(self.chunk, N, n1, ny)[:M].transpose(0, 1, 3, 2).reshape(M, N * ny, n1)
        b = self._b.reshape(self.chunk, N * ny)[:M].copy()
        return A, b


def _channel_gram(partition: Partition, x, z, xi2, masked: bool):
    """One sample's Gram entries per channel: the upper triangle of ``[A_j y_j]' [A_j y_j]``,
    ``y = z - b``, shape (T, n_outputs) with T = (n1+1)(n1+2)/2; with ``masked`` z is
    ``[z; m]`` and a channel's entries count only where it was measured."""
    n1 = partition.n_linear
    ny = z.numel() // (2 if masked else 1)
    A = partition.A(x, xi2) if n1 else ca.SX(ny, 0)
    y = z[:ny] - partition.b(x, xi2)
    rows, cols = np.triu_indices(n1 + 1)
    gram = []
    for j in range(ny):
        m = ca.horzcat(A[j, :], y[j])
        weight = z[ny + j] if masked else 1
        gram.append(ca.vertcat(*[weight * m[a] * m[b] for a, b in zip(rows, cols)]))
    return ca.horzcat(*gram)


class _GramEvaluator:
    """Per-channel Gram matrices ``sum_k [A_k y_k]' [A_k y_k]`` for chunks of candidates.

    ``y = z - b(xi2)``. The Gram entries are summed over samples inside one CasADi
    map-reduce, so A and b never reach memory: per candidate the sweep costs one pass
    over the data and returns (n1+1)(n1+2)/2 numbers per channel. Sub-expressions that
    depend only on the data (``x``, ``z``) are computed once for all candidates, those
    that depend only on xi2 once per candidate (``casadi.extract_parametric``). The
    least squares then take the normal equations of the column-scaled Gram matrix;
    candidates where that loses accuracy (scaled condition number above 1e10, or a
    residual below 1e-8 of ``y'y`` where the subtraction cancels) are re-solved by
    column-scaled QR on A itself (:class:`_BulkEvaluator`). Entries that are constant per
    sample are N times that constant and stay out of the loop; ``threads`` threads take
    contiguous parts of the candidates, each with its own buffer.
    """

    def __init__(self, partition: Partition, data: Dataset, n_candidates: int, jit: bool = False, threads: int = 1,
                 max_chunk: int = 4096):
        # n_candidates only sizes the chunks of candidates handled per call
        from .sums import evaluate, map_sum

        self.partition, self.data = partition, data
        self.n_samples = N = data.n_samples
        self.n_outputs = ny = data.outputs.shape[1]
        self.n1 = n1 = partition.n_linear
        self.n2 = n2 = partition.n_nonlinear
        ns = data.signals.shape[1]
        self.chunk = int(max(1, min(n_candidates, max_chunk)))
        # with missing outputs the data are [z; mask] per sample: a product counts only where measured
        self.masked = data.has_missing
        self.counts = data.observed_counts()
        x, xi2 = ca.SX.sym("x", ns), ca.SX.sym("xi2", n2)
        z = ca.SX.sym("z", 2 * ny if self.masked else ny)
        self._rows, self._cols = np.triu_indices(n1 + 1)
        G = self._split_constant_entries(_channel_gram(partition, x, z, xi2, self.masked), N)
        # hoist data-only and candidate-only sub-expressions out of the candidate x sample loop
        G1, feat_sym, feat_expr = ca.extract_parametric(G, ca.vertcat(x, z), {})
        G2, cand_sym, cand_expr = ca.extract_parametric(G1, xi2, {})
        f_sym = ca.vertcat(*[ca.vec(v) for v in feat_sym]) if feat_sym else ca.SX.sym("f_unused", 1)
        f_expr = ca.vertcat(*[ca.vec(v) for v in feat_expr]) if feat_expr else ca.SX.zeros(1)
        c_sym = ca.vertcat(*[ca.vec(v) for v in cand_sym]) if cand_sym else ca.SX.sym("c_unused", 1)
        c_expr = ca.vertcat(*[ca.vec(v) for v in cand_expr]) if cand_expr else ca.SX.zeros(1)
        features = ca.Function("gram_features", [x, z], [f_expr], ["x", "z"], ["f"])
        constants = ca.Function("gram_constants", [xi2], [c_expr], ["xi2"], ["c"])
        per_sample = ca.Function("gram_i", [x, z, f_sym, xi2, c_sym], [G2], ["x", "z", "f", "xi2", "c"], ["G"])
        # -O3 -march=native: the compiled loop runs on the machine that compiles it
        self._summed = map_sum(per_sample, N, 1, "gram_sum", jit, ("-O3", "-march=native"), n_data=3)
        self._constants = constants
        self._signals = np.ascontiguousarray(data.signals).reshape(-1)
        outputs = np.hstack([data.filled_outputs(), data.output_mask()]) if self.masked else data.outputs
        self._outputs = np.ascontiguousarray(outputs).reshape(-1)
        (per_sample_features,) = evaluate(features.map(N), data.signals.T, outputs.T)  # (n_f, N)
        self._features = np.ascontiguousarray(per_sample_features.reshape(-1, N).T).reshape(-1)
        # one buffer (own work memory, own candidate and result arrays) per thread; CasADi
        # releases the GIL while a compiled pass runs, so threads over candidates scale
        self.threads = max(1, int(threads))
        self._workers = [self._worker(c_sym.numel()) for _ in range(self.threads)]
        self._pool = None
        self._bulk = None
        self.n_fallback = 0

    def _split_constant_entries(self, gram: ca.SX, n_samples: int) -> ca.SX:
        """The per-sample Gram entries (T, ny) that vary between samples, as one column.

        Entries that are constant per sample (products with the zeros and ones of A, as for
        the columns of an offset) are N times that constant: they stay out of the loop over
        samples (``_fixed``, ``_fixed_sum``); ``_varying`` indexes the others in the flat
        (ny * T) layout, entry t + T*j.
        """
        G = ca.densify(ca.cse(gram))
        entries = [G.nz[k] for k in range(G.nnz())]
        self._varying = np.array([k for k, e in enumerate(entries) if not e.is_constant()], dtype=int)
        self._fixed = np.array([k for k, e in enumerate(entries) if e.is_constant()], dtype=int)
        self._fixed_sum = n_samples * np.array([float(ca.evalf(entries[k])) for k in self._fixed])
        return ca.vertcat(*[entries[k] for k in self._varying]) if len(self._varying) else ca.SX.zeros(1)

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

    def gram(self, xi2: np.ndarray) -> np.ndarray:
        """Gram matrices, shape (M, n_outputs, n1+1, n1+1), for M candidates (rows of xi2)."""
        M = xi2.shape[0]
        T, ny = len(self._rows), self.n_outputs
        consts = np.asarray(self._constants.map(M)(xi2.T), dtype=float).reshape(-1, M).T if M else np.zeros((0, 1))
        flat = np.empty((M, T * ny))
        flat[:, self._fixed] = self._fixed_sum
        varying = np.empty((M, len(self._workers[0][4])))
        parts = [p for p in np.array_split(np.arange(M), min(self.threads, max(M, 1))) if len(p)]
        if len(parts) <= 1:
            self._passes(0, xi2, consts, varying)
        else:
            if self._pool is None:
                from concurrent.futures import ThreadPoolExecutor

                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="casest_sweep")
            # contiguous parts: each thread writes its rows of ``varying`` in place
            futures = [self._pool.submit(self._passes, w, xi2[p], consts[p], varying[p[0] : p[-1] + 1])
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
    def bulk(self) -> "_BulkEvaluator":
        """A and b themselves (for the QR fallback and diagnostics), built on first use."""
        if self._bulk is None:
            self._bulk = _BulkEvaluator(self.partition, self.data, 64.0, 64)
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
            eig = np.linalg.eigvalsh(Ps)
            well = finite & (d > 0).all(axis=1) & (eig[:, 0] > 1e-10 * eig[:, -1])
            x = np.zeros((stop - start, n1))
            if well.any():
                x[well] = np.linalg.solve(Ps[well], (q / safe)[well][..., None])[..., 0] / safe[well]
            # per-channel residual sum of squares: y'y - 2 x'A'y + x'A'A x
            rss = yty - 2 * np.einsum("mjn,mn->mj", Aty, x) + np.einsum("mn,mjnk,mk->mj", x, AtA, x)
            accurate = well & np.all(rss > 1e-8 * yty, axis=1)
            x, rss = _feasible(AtA, Aty, yty, x, rss, accurate, lb, ub)
            xi1[start:stop][accurate] = x[accurate]
            R[start:stop][accurate] = rss[accurate] / self.counts
            ok[start:stop] = accurate
            redo[start:stop] = ~accurate & finite
        if redo.any():
            idx = np.flatnonzero(redo)
            self.n_fallback += len(idx)
            xi1[idx], R[idx], ok[idx] = _evaluate_qr(self.bulk, self.data.outputs, cands[idx], lb, ub)
        return xi1, R, ok


class _DynamicGramEvaluator(_GramEvaluator):
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
                 jit: bool = False, threads: int = 1, max_chunk: int = 4096):
        from .numerics import compile_function

        self.model, self.partition, self.data = model, partition, data
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
        gram = self._split_constant_entries(_channel_gram(partition, s, z, xi2, self.masked), N)
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
        u_k, z_k = d[2 * nuk + 1: 2 * nuk + 1 + nu], d[2 * nuk + 1 + nu:]
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
        G = total + per_sample(ca.vertcat(x_end, last[:nu]), last[nu:], xi2_m)
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
            if self._pool is None:
                from concurrent.futures import ThreadPoolExecutor

                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="casest_sweep")
            futures = [self._pool.submit(self._dyn_passes, w, xi2[p], varying[p[0]: p[-1] + 1])
                       for w, p in enumerate(parts)]
            for future in futures:
                future.result()
        flat[:, self._varying] = varying[:, : len(self._varying)]
        return self._matrices(flat)

    @property
    def bulk(self) -> "_DynamicBulkEvaluator":
        if self._bulk is None:
            self._bulk = _DynamicBulkEvaluator(self.model, self.partition, self.data)
        return self._bulk


class _DynamicBulkEvaluator:
    """A and b of a dynamic model for one candidate at a time (the QR fallback and diagnostics)."""

    def __init__(self, model: DynamicModel, partition: Partition, data: Dataset):
        self.n_samples = N = data.n_samples
        self.n_outputs = ny = data.outputs.shape[1]
        self.mask = data.output_mask().reshape(-1)
        self.counts = data.observed_counts()
        self.n1, self.n2 = partition.n_linear, partition.n_nonlinear
        self.chunk = 1
        xi2 = ca.MX.sym("xi2", self.n2)
        T, U = ca.MX.sym("t", 1, N), ca.MX.sym("u", len(model.inputs), N)
        d0 = ca.MX.sym("x0_data", len(model.initial_from_data))
        X = model.trajectory_symbols(partition.assemble_symbolic(ca.MX.zeros(self.n1), xi2), d0, T, U)
        S = ca.vertcat(X, U)
        A_all = partition.A.map(N)(S, xi2) if self.n1 else ca.MX(ny, 0)
        self._fn = ca.Function("dyn_Ab", [xi2, T, U, d0], [A_all, partition.b.map(N)(S, xi2)])
        self._args = [data.signals[:, 0][None, :], data.signals[:, 1:].T, model.initial_values(data)]

    def __call__(self, xi2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A of shape (M, N*n_outputs, n1) and b of shape (M, N*n_outputs)."""
        N, ny, n1 = self.n_samples, self.n_outputs, self.n1
        As, bs = [], []
        for row in np.atleast_2d(xi2):
            A, b = self._fn(row, *self._args)
            As.append(np.asarray(A).reshape(-1, order="F").reshape(N, n1, ny).transpose(0, 2, 1).reshape(N * ny, n1))
            bs.append(np.asarray(b).reshape(-1, order="F"))
        return np.array(As), np.array(bs)


def batched_least_squares(
    A: np.ndarray, y: np.ndarray, rcond: float = 1e-11
) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``min ||A_m x - y_m||`` for a stack of problems by column-scaled QR.

    Parameters
    ----------
    A : ndarray, shape (M, K, n)
    y : ndarray, shape (M, K)
    rcond : float
        A problem whose scaled triangular factor has ``min|diag| / max|diag| < rcond``
        is treated as rank-deficient.

    Returns
    -------
    x : ndarray, shape (M, n)
        Solutions; NaN rows for rank-deficient problems.
    full_rank : ndarray of bool, shape (M,)
    """
    M, K, n = A.shape
    finite = np.isfinite(A).all(axis=(1, 2)) & np.isfinite(y).all(axis=1)
    if n == 0:
        return np.zeros((M, 0)), finite
    if not finite.all():  # a model that is NaN or infinite somewhere: no fit there
        A, y = np.where(finite[:, None, None], A, 0.0), np.where(finite[:, None], y, 0.0)
    norms = np.linalg.norm(A, axis=1)  # (M, n)
    safe = np.where(norms > 0, norms, 1.0)
    Q, Rf = np.linalg.qr(A / safe[:, None, :])
    diag = np.abs(np.diagonal(Rf, axis1=1, axis2=2))
    full_rank = finite & (norms > 0).all(axis=1) & (diag.min(axis=1) > rcond * diag.max(axis=1))
    qty = np.einsum("mkn,mk->mn", Q, y)
    x = np.full((M, n), np.nan)
    if full_rank.any():
        sol = np.linalg.solve(Rf[full_rank], qty[full_rank][..., None])[..., 0]
        x[full_rank] = sol / safe[full_rank]
    return x, full_rank


def box_least_squares(P: np.ndarray, q: np.ndarray, lb: np.ndarray, ub: np.ndarray, max_iter: int = 50) -> np.ndarray:
    """Solve ``min x'Px - 2 q'x`` subject to ``lb <= x <= ub`` for a stack of problems.

    The bounded linear least squares ``min ||A x - y||`` with ``P = A'A``, ``q = A'y``,
    exact for the small numbers of linear parameters of calibration models. Primal-dual
    active-set iteration (Hintermueller, Ito and Kunisch 2002) on the column-scaled
    problem, all problems at once; the few that do not settle in ``max_iter`` passes are
    solved one by one by SciPy's bounded-variable least squares on the Cholesky factor.

    Parameters
    ----------
    P : ndarray, shape (M, n, n)
        Symmetric positive definite Gram matrices.
    q : ndarray, shape (M, n)
    lb, ub : ndarray, shape (n,)
        Bounds (``-inf``/``inf`` for none).
    max_iter : int

    Returns
    -------
    x : ndarray, shape (M, n)
    """
    M, n = q.shape
    d = np.sqrt(np.maximum(np.diagonal(P, axis1=1, axis2=2), 1e-300))
    Ps = P / (d[:, :, None] * d[:, None, :])
    qs = q / d
    lo, hi = lb[None, :] * d, ub[None, :] * d
    y = np.linalg.solve(Ps, qs[..., None])[..., 0]  # the unconstrained solutions
    mu = np.zeros((M, n))  # multipliers: qs - Ps y on the active set, 0 on the free set
    lower = np.zeros((M, n), dtype=bool)
    upper = np.zeros((M, n), dtype=bool)
    todo = np.ones(M, dtype=bool)
    eye = np.eye(n)
    for _ in range(max_iter):
        new_lower = (y + mu < lo) & todo[:, None]
        new_upper = (y + mu > hi) & todo[:, None] & ~new_lower
        settled = todo & np.all(new_lower == lower, axis=1) & np.all(new_upper == upper, axis=1)
        todo &= ~settled
        if not todo.any():
            break
        lower[todo], upper[todo] = new_lower[todo], new_upper[todo]
        active = (lower | upper)[todo]
        K = np.where(active[:, :, None], eye[None], Ps[todo])
        rhs = np.where(lower[todo], lo[todo], np.where(upper[todo], hi[todo], qs[todo]))
        y[todo] = np.linalg.solve(K, rhs[..., None])[..., 0]
        grad = qs[todo] - np.einsum("mij,mj->mi", Ps[todo], y[todo])
        mu[todo] = np.where(active, grad, 0.0)
    x = y / d
    if todo.any():
        from scipy.optimize import lsq_linear

        for m in np.flatnonzero(todo):
            L = np.linalg.cholesky(P[m])
            x[m] = lsq_linear(L.T, np.linalg.solve(L, q[m]), bounds=(lb, ub), method="bvls", tol=1e-14).x
    return np.clip(x, lb, ub)


def _feasible(AtA, Aty, yty, x, rss, ok, lb, ub):
    """Replace the xi1 (and per-channel RSS) that leave the box by the best feasible ones."""
    if lb is None or x.shape[1] == 0:
        return x, rss
    outside = ok & np.any((x < lb) | (x > ub), axis=1)
    if not outside.any():
        return x, rss
    x, rss = x.copy(), rss.copy()
    P, q = AtA[outside].sum(axis=1), Aty[outside].sum(axis=1)
    xb = box_least_squares(P, q, lb, ub)
    x[outside] = xb
    sub_AtA, sub_Aty = AtA[outside], Aty[outside]
    rss[outside] = np.maximum(
        yty[outside] - 2 * np.einsum("mjn,mn->mj", sub_Aty, xb) + np.einsum("mn,mjnk,mk->mj", xb, sub_AtA, xb), 0.0
    )
    return x, rss


def _evaluate(evaluator, Z: np.ndarray, cands: np.ndarray, lb: np.ndarray | None = None,
              ub: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """xi1 (M, n1), R (M, n_outputs) and a full-rank mask (M,) for all candidates.

    ``lb, ub`` (shape (n1,)): the bounds of xi1; each candidate then gets its best
    feasible xi1.
    """
    if isinstance(evaluator, _GramEvaluator):
        return evaluator.solve(cands, lb, ub)
    return _evaluate_qr(evaluator, Z, cands, lb, ub)


def _evaluate_all(evaluator, Z, cands, bounds, progress: bool, block: int = 4096):
    """:func:`_evaluate` for all candidates, with a tqdm progress bar on large sweeps."""
    bar = None
    if progress and len(cands) > 2 * block:
        try:
            from tqdm import tqdm

            bar = tqdm(total=len(cands), unit="cand", desc="stage 1", leave=False)
        except ImportError:  # tqdm is optional (extra "parallel")
            bar = None
    if bar is None:
        return _evaluate(evaluator, Z, cands, *bounds)
    parts = []
    try:
        for start in range(0, len(cands), block):
            parts.append(_evaluate(evaluator, Z, cands[start:start + block], *bounds))
            bar.update(min(block, len(cands) - start))
    finally:
        bar.close()
    return tuple(np.concatenate([p[k] for p in parts]) for k in range(3))


def _evaluate_qr(evaluator: _BulkEvaluator, Z: np.ndarray, cands: np.ndarray, lb: np.ndarray | None = None,
                 ub: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """As :func:`_evaluate`, by column-scaled QR on A and b themselves."""
    M = cands.shape[0]
    N, ny, n1 = evaluator.n_samples, evaluator.n_outputs, evaluator.n1
    chunk = evaluator.chunk
    xi1 = np.empty((M, n1))
    R = np.empty((M, ny))
    ok = np.empty(M, dtype=bool)
    z = np.nan_to_num(Z).reshape(-1)  # sample-major, channel-minor: matches the A, b rows
    mask = evaluator.mask
    for start in range(0, M, chunk):
        stop = min(M, start + chunk)
        A, b = evaluator(cands[start:stop])
        y = (z[None, :] - b) * mask
        A = A * mask[None, :, None]
        x, full = batched_least_squares(A, y)
        if lb is not None and n1 and np.any(full & np.any((x < lb) | (x > ub), axis=1)):
            Ac, yc = A.reshape(stop - start, N, ny, n1), y.reshape(stop - start, N, ny)
            AtA = np.einsum("mkji,mkjl->mjil", Ac, Ac)
            Aty = np.einsum("mkji,mkj->mji", Ac, yc)
            x, _ = _feasible(AtA, Aty, np.einsum("mkj,mkj->mj", yc, yc), np.nan_to_num(x), np.zeros((stop - start, ny)),
                             full, lb, ub)
            x[~full] = np.nan
        resid = y - np.einsum("mkn,mn->mk", A, np.nan_to_num(x)) if n1 else y
        xi1[start:stop] = x
        R[start:stop] = np.sum(resid.reshape(stop - start, N, ny) ** 2, axis=1) / evaluator.counts
        ok[start:stop] = full & np.isfinite(R[start:stop]).all(axis=1)
    R[~ok] = np.nan
    return xi1, R, ok


# ----------------------------------------------------------------------------- minima
def _to_unit(cands: np.ndarray, params) -> np.ndarray:
    """Candidates mapped through their priors' CDFs to [0, 1]^n2."""
    if not params:
        return cands
    return np.column_stack(
        [np.clip(p.sampling_prior.cdf(cands[:, j], p.lb, p.ub), 0.0, 1.0) for j, p in enumerate(params)]
    )


def _nearest_neighbours(points: np.ndarray, k: int, block: int = 512) -> np.ndarray:
    """Indices of each point's k nearest other points, shape (M, k).

    Blocked NumPy distances up to 8192 points (importing scipy.spatial costs more than the
    search there); a k-d tree beyond.
    """
    M = points.shape[0]
    if M > 8192:
        from scipy.spatial import cKDTree

        return cKDTree(points).query(points, k=k + 1)[1][:, 1:]
    sq = np.einsum("ij,ij->i", points, points)
    out = np.empty((M, k), dtype=np.intp)
    for start in range(0, M, block):
        rows = slice(start, min(start + block, M))
        d2 = sq[rows, None] + sq[None, :] - 2.0 * points[rows] @ points.T
        d2[np.arange(d2.shape[0]), np.arange(start, rows.stop)] = np.inf  # not its own neighbour
        near = np.argpartition(d2, k - 1, axis=1)[:, :k]
        out[rows] = near
    return out


def _local_minima(unit: np.ndarray, trace: np.ndarray, grid_shape) -> np.ndarray:
    """Indices of candidates not above any neighbour (grid axes, or k nearest in ``unit``)."""
    M, n2 = unit.shape
    if M == 1:
        return np.array([0])
    t = np.where(np.isfinite(trace), trace, np.inf)
    if grid_shape is not None:
        grid = t.reshape(grid_shape)
        is_min = np.isfinite(grid)
        for axis in range(n2):
            for shift in (1, -1):
                neighbour = np.roll(grid, shift, axis=axis)
                edge = [slice(None)] * n2
                edge[axis] = 0 if shift == 1 else -1
                neighbour[tuple(edge)] = np.inf
                is_min &= grid <= neighbour
        idx = np.flatnonzero(is_min.reshape(-1))
    else:
        k = min(M - 1, 2 * n2 + 2)
        nb = _nearest_neighbours(unit, k)
        idx = np.flatnonzero(np.isfinite(t) & (t <= t[nb].min(axis=1)))
    return idx[np.argsort(t[idx], kind="stable")]


def _profile_cost(R: np.ndarray, counts) -> np.ndarray:
    """sum_j N_j/2 ln R_j: the ML cost with R at its optimum (constants dropped); ``counts`` N_j or N."""
    return 0.5 * np.sum(np.asarray(counts) * np.log(np.maximum(R, 1e-300)), axis=-1)


def _competing_minima(evaluator, Z, cands, R, minima, counts, confidence, bounds=(None, None)) -> np.ndarray:
    """Minima that fit as well as the best (likelihood-ratio test) behind a real ridge.

    A local minimum competes when its profile cost N/2 ln|R| is within
    chi2(confidence, n2)/2 of the best one's and the straight path between them rises
    above both ends by more than chi2(confidence, 1)/2. All paths are evaluated in one
    batch.
    """
    if len(minima) < 2:
        return np.array([], dtype=int)
    n2 = cands.shape[1]
    cost = _profile_cost(R[minima], counts)
    from scipy.special import chdtri  # the chi-square quantile, without importing scipy.stats

    equivalent_gap = 0.5 * chdtri(n2, 1.0 - confidence)
    ridge_gap = 0.5 * chdtri(1, 1.0 - confidence)
    best = minima[0]
    close = [(m, c) for m, c in zip(minima[1:], cost[1:]) if c - cost[0] <= equivalent_gap]
    if not close:
        return np.array([], dtype=int)
    fractions = np.linspace(0.0, 1.0, 19)[1:-1]
    paths = np.concatenate(
        [cands[best][None, :] + fractions[:, None] * (cands[m] - cands[best])[None, :] for m, _ in close]
    )
    _, R_path, ok = _evaluate(evaluator, Z, paths, *bounds)
    path_cost = _profile_cost(np.where(ok[:, None], R_path, np.inf), counts).reshape(len(close), -1)
    competing = [m for (m, c), pc in zip(close, path_cost) if np.max(pc) - max(cost[0], c) > ridge_gap]
    return np.array(competing, dtype=int)


# ----------------------------------------------------------------------------- Eq. 17, 18
def _validity_conditions(
    model: Model, partition: Partition, data: Dataset, xi1: np.ndarray, xi2: np.ndarray, step: np.ndarray,
    R: np.ndarray | None = None, density: np.ndarray | None = None,
) -> tuple[float, float, list[str], float]:
    """Eq. 17 ratio, Eq. 18 smallest normalised eigenvalue, the weakest xi2 names, flat spread.

    ``R`` (per channel) weights the profile information; ``density`` (prior densities of
    xi2 at the candidate, shape (n2,)) turns its weakest direction into prior-CDF units:
    the returned spread is the one-sigma interval of that direction there (``inf`` when
    the information is singular).
    """
    theta = partition.assemble(xi1, xi2)
    xi2_idx = list(partition.nonlinear_index)
    h, J = measurement_of(model).prediction_and_jacobian(theta, data)  # a dynamic model's: through the states
    mask = data.output_mask().reshape(-1)  # outputs not measured leave the checks
    h, J = h * mask, J * mask[:, None]
    J2 = J[:, xi2_idx]
    J1 = J[:, list(partition.linear_index)]
    ratio = float(np.linalg.norm(J2 @ step) / max(np.linalg.norm(h), 1e-300))
    J2p = _project_out(J1, J2)
    P = J2p.T @ J2p
    spread = math.inf
    if R is not None and density is not None:
        # the same projection with each channel weighted by 1/R_j: the profile Fisher information
        w = np.tile(1.0 / np.sqrt(np.maximum(np.asarray(R, dtype=float), 1e-300)), data.n_samples)
        J2w = _project_out(J1 * w[:, None], J2 * w[:, None])
        info_u = (J2w.T @ J2w) / np.outer(density, density)
        lam = np.linalg.eigvalsh(0.5 * (info_u + info_u.T))[0] if np.all(density > 0) else 0.0
        spread = float(1.0 / math.sqrt(lam)) if lam > 0 else math.inf
    d = np.sqrt(np.diag(P))
    if np.any(d == 0):
        return ratio, 0.0, [partition.nonlinear[i] for i in np.flatnonzero(d == 0)], spread
    Pn = P / np.outer(d, d)
    w, V = np.linalg.eigh(Pn)
    weak = [partition.nonlinear[i] for i in np.flatnonzero(np.abs(V[:, 0]) > 0.3)]
    return ratio, float(w[0]), weak, spread


def _project_out(J1: np.ndarray, J2: np.ndarray) -> np.ndarray:
    """J2 with the span of J1's columns removed (the profile over the linear parameters)."""
    if not J1.shape[1]:
        return J2
    Q, _ = np.linalg.qr(J1)
    return J2 - Q @ (Q.T @ J2)


def _prior_density(params, xi2: np.ndarray) -> np.ndarray:
    """d(prior CDF)/d(xi2) at ``xi2`` by central differences, shape (n2,)."""
    out = []
    for j, p in enumerate(params):
        h = 1e-6 * max(abs(xi2[j]), p.typical_scale)
        lo, hi = max(xi2[j] - h, p.lb), min(xi2[j] + h, p.ub)
        c = p.sampling_prior.cdf(np.array([lo, hi]), p.lb, p.ub)
        out.append((c[1] - c[0]) / (hi - lo) if hi > lo else 0.0)
    return np.array(out, dtype=float)


def _local_design(center: np.ndarray, step: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """Points around ``center`` at +-``step``: a 3**n2 grid up to n2 = 4, the 2 n2 axis points above."""
    n2 = len(center)
    if n2 <= 4:
        offsets = np.array(np.meshgrid(*[[-1.0, 0.0, 1.0]] * n2, indexing="ij")).reshape(n2, -1).T
        offsets = offsets[np.any(offsets != 0, axis=1)]
    else:
        offsets = np.vstack([np.eye(n2), -np.eye(n2)])
    pts = np.clip(center[None, :] + offsets * step[None, :], lb, ub)
    return np.unique(pts[np.any(pts != center[None, :], axis=1)], axis=0)


def check_predictions(model: Model, data: Dataset, theta: np.ndarray, label: str) -> None:
    """Raise a :class:`ModelError` naming the output and samples where the model is NaN or infinite.

    Parameters
    ----------
    theta : ndarray, shape (n_parameters,)
    label : str
        What ``theta`` is, for the message (e.g. "nominal values").
    """
    with np.errstate(all="ignore"):
        pred = measurement_of(model).predict(theta, data)
    bad = ~np.isfinite(pred)
    if not bad.any():
        return
    j = int(np.flatnonzero(bad.any(axis=0))[0])
    rows = np.flatnonzero(bad[:, j])
    shown = ", ".join(str(r) for r in rows[:5]) + (" ..." if rows.size > 5 else "")
    where = ", ".join(f"{n} = {v:.6g}" for n, v in zip(model.signal_names, data.signals[rows[0]]))
    raise ModelError(
        f"output {model.output_names[j]!r} is NaN or infinite at {rows.size} of {data.n_samples} samples (rows "
        f"{shown}, 0-based) at the {label}; at row {rows[0]}: {where or 'no signals'}. The model is not defined "
        "there (a log or sqrt of a negative number, a division by zero?): drop those samples, or change the model "
        f"or the {label}"
    )


def _unidentifiable_linear(evaluator, cand: np.ndarray, names: Sequence[str]) -> list[str]:
    evaluator = evaluator.bulk if isinstance(evaluator, _GramEvaluator) else evaluator
    A, _ = evaluator(cand[None, :])
    A = A[0]
    norms = np.linalg.norm(A, axis=0)
    if np.any(norms == 0):
        return [names[i] for i in np.flatnonzero(norms == 0)]
    _, _, Vt = np.linalg.svd(A / norms, full_matrices=False)
    return [names[i] for i in np.flatnonzero(np.abs(Vt[-1]) > 0.3)]


# ----------------------------------------------------------------------------- sweep
def sweep(
    model: Model | Problem,
    data: Dataset | None = None,
    partition: Partition | None = None,
    settings: SweepSettings | None = None,
    candidates: np.ndarray | None = None,
    progress: bool = False,
) -> Landscape:
    """Run stage 1: sample xi2, solve xi1 by linear least squares, judge the landscape.

    Parameters
    ----------
    model : Model or Problem
        A :class:`casest.Problem` sweeps its stage-1 data (its experiments stacked, fixed
        parameters substituted); with known noise the residuals are weighted by the known
        std, so Tr[R] is in units of the known variances.
    data : Dataset
        Samples used for the sweep (may differ from the stage-2 data, paper Table 5); not
        with a Problem.
    partition : Partition, optional
        Default: :func:`casest.separate` of the (problem's) model.
    settings : SweepSettings, optional
    candidates : ndarray, shape (M, n2), optional
        Explicit xi2 candidates (physical units); overrides the design.
    progress : bool
        Show a progress bar (tqdm, if installed) on sweeps of more than 8192 candidates.

    Returns
    -------
    Landscape

    Raises
    ------
    IdentifiabilityError
        ``A(xi2)`` is rank-deficient at every candidate; the message names the linear
        parameters that the data cannot separate.
    """
    from .separate import separate

    t0 = time.perf_counter()
    settings = settings or SweepSettings()
    if isinstance(model, Problem):
        if data is not None:
            raise OptionError("sweep(problem) takes its data from the problem (Problem(..., stage1_data=...))")
        problem = model
        model, data, weighted = problem.stage1_inputs()
        partition = partition or separate(problem.model)
        if weighted:  # the weighted outputs keep the split of the problem's model
            partition = separate(model, linear=partition.linear, nonlinear=partition.nonlinear)
    elif data is None:
        raise OptionError("sweep needs the data (or a casest.Problem)")
    measurement = measurement_of(model)
    measurement.check_data(data)
    partition = partition or separate(model)
    nonlin_params = [model.parameters[i] for i in partition.nonlinear_index]
    if candidates is not None:
        cands = np.asarray(candidates, dtype=float).reshape(-1, partition.n_nonlinear)
        lb = np.array([p.lb for p in nonlin_params])
        ub = np.array([p.ub for p in nonlin_params])
        outside = np.any((cands < lb) | (cands > ub), axis=0)
        if np.any(outside):
            raise ModelError(
                f"explicit candidates for {[p.name for p in np.array(nonlin_params)[outside]]} "
                "lie outside the parameter bounds"
            )
        design, grid_shape = "explicit", None
    else:
        cands, design, grid_shape = draw_candidates(model, partition, settings)
    # the nominal xi2 (the user's best guess) is evaluated beside the design, not in it
    nominal = model.nominal[list(partition.nonlinear_index)][None, :] if partition.n_nonlinear else np.zeros((0, 0))
    n_eval = len(cands) + len(nominal)
    if measurement.simulated:  # the states are simulated per candidate
        evaluator = _DynamicGramEvaluator(model, partition, data, n_eval, settings.resolved_jit(data.n_samples, n_eval),
                                          settings.resolved_threads(n_eval))
    elif settings.method == "gram":
        evaluator = _GramEvaluator(partition, data, n_eval, settings.resolved_jit(data.n_samples, n_eval),
                                   settings.resolved_threads(n_eval))
    else:
        evaluator = _BulkEvaluator(partition, data, settings.memory_mb, n_eval, settings.resolved_jit(data.n_samples, n_eval))
    # candidates are ranked by the best *feasible* xi1: an alias that needs xi1 outside its
    # box (a scale factor 1 + s = -1, say) must not win stage 1
    lin = list(partition.linear_index)
    lb1, ub1 = model.lower_bounds[lin], model.upper_bounds[lin]
    bounds = (lb1, ub1) if np.any(np.isfinite(lb1) | np.isfinite(ub1)) else (None, None)
    xi1, R, ok = _evaluate_all(evaluator, data.outputs, np.vstack([cands, nominal]) if len(nominal) else cands, bounds,
                               progress)
    nominal_xi1 = nominal_R = None
    if len(nominal):
        nominal_xi1, nominal_R = xi1[-1].copy(), R[-1].copy()
        xi1, R, ok = xi1[:-1], R[:-1], ok[:-1]
    if not ok.any():
        check_predictions(model, data, model.nominal, "nominal values")
        names = _unidentifiable_linear(evaluator, cands[0], partition.linear)
        raise IdentifiabilityError(
            f"A(xi2) is rank-deficient at every one of {len(cands)} candidates: the data cannot "
            f"separate the linear parameters {names}. Fix one of them (remove it from the model "
            "or give it equal bounds) or collect data that excite them differently"
        )
    trace = np.where(ok, R.sum(axis=1), np.inf)
    counts = data.observed_counts()

    def ranked(R_, ok_):
        if settings.criterion == "trace":
            return np.where(ok_, R_.sum(axis=1), np.inf)
        return np.where(ok_, _profile_cost(np.where(ok_[:, None], R_, 1.0), counts), np.inf)

    rank = ranked(R, ok)
    ranked_name = "Tr[R]" if settings.criterion == "trace" else "the profile ML cost"
    n2 = partition.n_nonlinear
    # neighbourhoods of scattered designs are measured in prior-probability coordinates
    unit = _to_unit(cands, nonlin_params)
    minima = _local_minima(unit, rank, grid_shape) if n2 else np.array([0])
    best = int(minima[0]) if len(minima) else int(np.argmin(rank))
    if len(minima) == 0 or minima[0] != best:
        minima = np.concatenate([[best], minima[minima != best]]).astype(int)

    ratio = eig = spread = None
    n_design = len(cands)
    if n2 == 0:
        verdict, reason = "linear", "no parameter is swept: stage 1 is one linear least squares"
        competing = np.array([], dtype=int)
    else:
        competing = _competing_minima(evaluator, data.outputs, cands, R, minima, data.observed_counts(), settings.confidence,
                                      bounds)
        step = _half_step(cands, unit, grid_shape, nonlin_params, best)
        lb2 = np.array([p.lb for p in nonlin_params])
        ub2 = np.array([p.ub for p in nonlin_params])

        def conditions(k):
            density = _prior_density(nonlin_params, cands[k])
            return _validity_conditions(model, partition, data, xi1[k], cands[k], step, R[k], density)

        ratio, eig, weak, spread = conditions(best)
        # Eq. 17 fails: refine the sweep around the best candidate (half the step each time)
        refinements = 0
        while ratio > settings.linearization_tol and refinements < settings.max_refinements and np.any(step > 0):
            local = _local_design(cands[best], step, lb2, ub2)
            step = 0.5 * step
            refinements += 1
            if len(local):
                xi1_l, R_l, ok_l = _evaluate(evaluator, data.outputs, local, *bounds)
                cands, xi1, R = np.vstack([cands, local]), np.vstack([xi1, xi1_l]), np.vstack([R, R_l])
                trace = np.concatenate([trace, np.where(ok_l, R_l.sum(axis=1), np.inf)])
                rank = np.concatenate([rank, ranked(R_l, ok_l)])
                if np.min(rank[-len(local):]) < rank[best]:
                    best = len(rank) - len(local) + int(np.argmin(rank[-len(local):]))
            ratio, eig, weak, spread = conditions(best)
        minima = np.concatenate([[best], minima[1:]]).astype(int)
        refined = f" after {refinements} local refinement(s) of the sweep around the best candidate" if refinements else ""
        if len(competing):
            where = "; ".join(
                ", ".join(f"{n} = {v:.4g}" for n, v in zip(partition.nonlinear, cands[m]))
                for m in competing[:3]
            )
            verdict = "multiple"
            profile = _profile_cost(R[np.concatenate([[best], competing])], counts)
            better = settings.criterion == "trace" and len(model.output_names) > 1 and profile[1:].min() < profile[0]
            hint = ("; by the likelihood one of them fits better than the best Tr[R], which is dominated by the "
                    "channels with the largest numbers: rank by SweepSettings(criterion='likelihood') when the "
                    "channels are in different units" if better else "")
            reason = (
                f"{len(competing)} other local minimum/minima of {ranked_name} lie in separate basins and "
                f"fit as well as the best at the {settings.confidence:.0%} level ({where}){hint}"
            )
        elif eig < settings.curvature_tol or spread > settings.flat_spread:
            verdict = "flat"
            why = (f"the profile curvature in xi2 is nearly singular (smallest normalised eigenvalue {eig:.3g} < "
                   f"{settings.curvature_tol:g})" if eig < settings.curvature_tol else
                   f"the data determine xi2 only to a one-sigma interval spanning {spread:.3g} of its swept prior "
                   f"mass (> {settings.flat_spread:g})")
            reason = f"the curvature check (paper Eq. 18) fails at the best candidate: {why}; weakly determined: {weak}"
        elif ratio > settings.linearization_tol:
            verdict = "coarse"
            reason = (
                f"the linearisation check (paper Eq. 17) fails{refined}: half a sweep step changes the prediction by {ratio:.3g} "
                f"(> {settings.linearization_tol:g}) of its norm; use more candidates"
            )
        else:
            extra = f" ({len(minima) - 1} shallower local minima do not compete)" if len(minima) > 1 else ""
            verdict = "unique"
            reason = (f"one clear minimum of {ranked_name}{extra}; the linearisation (paper Eq. 17) and curvature (Eq. 18) "
                      f"checks hold{refined}")
    return Landscape(
        nonlinear=partition.nonlinear,
        linear=partition.linear,
        output_names=model.output_names,
        candidates=cands,
        xi1=xi1,
        R=R,
        trace_R=trace,
        best_index=best,
        local_minima=np.asarray(minima, dtype=int),
        competing=competing,
        verdict=verdict,
        reason=reason,
        # variable projection (reduced) from every start; full when there is nothing to project
        recommended_mode="reduced" if partition.n_linear and n2 else "full",
        design=design,
        grid_shape=grid_shape,
        linearization_ratio=ratio,
        curvature_min_eig=eig,
        n_samples=data.n_samples,
        seconds=time.perf_counter() - t0,
        nominal_xi1=nominal_xi1,
        nominal_R=nominal_R,
        n_design=n_design,
        flat_spread=spread if n2 else None,
        criterion=settings.criterion,
        ranking=rank,
    )


def _half_step(cands: np.ndarray, unit: np.ndarray, grid_shape, params, best: int) -> np.ndarray:
    """Half the local sampling distance per xi2 component (the Delta xi2 of Eq. 17)."""
    if grid_shape is not None:
        steps = []
        for j in range(cands.shape[1]):
            axis = np.unique(cands[:, j])
            if axis.size < 2:
                steps.append(0.0)
                continue
            pos = int(np.searchsorted(axis, cands[best, j]))
            gaps = np.diff(axis)[max(pos - 1, 0) : pos + 1]
            steps.append(float(np.max(gaps)))
        return 0.5 * np.array(steps)
    if cands.shape[0] < 2:
        return np.zeros(cands.shape[1])
    nearest = _nearest_neighbours(unit, 1)[:, 0]
    dist = np.linalg.norm(unit - unit[nearest], axis=1)
    du = 0.5 * np.median(dist) / math.sqrt(cands.shape[1])
    steps = []
    for j, p in enumerate(params):
        u = unit[best, j]
        lo, hi = p.sampling_prior.ppf(np.array([max(u - du, 0.0), min(u + du, 1.0)]), p.lb, p.ub)
        steps.append(0.5 * abs(hi - lo))
    return np.array(steps)
