"""Sums over samples of per-sample functions and their exact derivatives.

The ML cost of Eq. 6 is a sum over samples, and so are its gradient and Hessian. Each is
built here once per model as a small SX function of one sample (exact symbolic
derivatives) and mapped over the N samples with CasADi's map-reduce: the sum is
accumulated inside the map, so no N-long intermediate is stored. With ``jit`` each
block's loop is compiled to C; with ``threads > 1`` the samples are split into equal
blocks evaluated on separate threads. The expression graph has a fixed number of nodes
whatever N is; building still costs time and memory linear in N (CasADi stores the
sparsity pattern of every N-long input), about 1 s per function at N = 10^6.
"""

from __future__ import annotations


import casadi as ca
import numpy as np

from .model import Model
from .numerics import (  # noqa: F401  (re-exported: the sums' public helpers)
    StructureCache,
    MIN_SAMPLES_PER_THREAD,
    available_cores,
    compile_function,
    compiler_available,
    default_threads,
    evaluate,
)

__all__ = ["map_sum", "MLSums", "ml_sums", "per_sample_cost", "residual_jacobian", "prediction_and_jacobian", "compiler_available", "default_threads", "evaluate"]

#: Samples per compiled block of a sum over at least 16 such blocks: the compiled code does
#: not depend on N, so one library serves long records of any length.
SUM_BLOCK = 4096


def map_sum(per_sample: ca.Function, n_samples: int, threads: int = 1, name: str | None = None,
            jit: bool = False, jit_flags=("-O2",), n_data: int = 2) -> ca.Function:
    """Map ``per_sample`` over samples and sum its outputs.

    Parameters
    ----------
    per_sample : casadi.Function
        Inputs ``(x, z, *rest)``: one sample's column vectors first (``n_data`` of them),
        then inputs shared by all samples.
    n_samples : int
        N.
    threads : int
        Evaluate the blocks of samples (``SUM_BLOCK`` each from N = 16 ``SUM_BLOCK``, else
        N / threads) on this many threads (1: serial).
    jit : bool
        Compile each block's loop (the map-reduce over its samples, with the per-sample
        function inlined) to C; about 0.1-0.3 s per function.
    n_data : int
        Number of leading per-sample inputs.

    Returns
    -------
    casadi.Function
        ``(X[n_x x N], Z[n_z x N], *rest) -> sums``, each output of ``per_sample`` summed
        over the N samples (same shape and sparsity).
    """
    name = name or per_sample.name() + "_sum"
    shared = list(range(n_data, per_sample.n_in()))
    all_out = list(range(per_sample.n_out()))
    data = [ca.MX.sym(per_sample.name_in(k) + "_all", per_sample.size1_in(k), n_samples) for k in range(n_data)]
    rest = [ca.MX.sym(per_sample.name_in(k), per_sample.sparsity_in(k)) for k in shared]

    def summed(count: int, label: str) -> ca.Function:
        loop = per_sample.map(f"{name}_{label}", "serial", count, shared, all_out)
        return compile_function(loop, jit_flags) if jit else loop

    def as_list(out) -> list:
        return list(out) if isinstance(out, (list, tuple)) else [out]

    threads = int(max(1, min(threads, n_samples)))
    long_record = n_samples >= 16 * SUM_BLOCK
    if threads == 1 and not long_record:
        return ca.Function(name, data + rest, as_list(summed(n_samples, "all")(*(data + rest))))
    # long records: blocks of a fixed size, so that one compiled block function serves every
    # N (the padding wastes < 1/16); shorter ones: one block per thread. The data are padded
    # with copies of the last sample, whose extra terms are subtracted afterwards (one
    # sample, evaluated once), so that every block has the same size
    size = SUM_BLOCK if long_record else -(-n_samples // threads)
    n_blocks = -(-n_samples // size)
    pad = n_blocks * size - n_samples
    if pad:
        # horzsplit keeps only offsets; indexing d[:, a:b] would store N-long index vectors
        last = [ca.horzsplit(d, [0, n_samples - 1, n_samples])[1] for d in data]
        padded = [ca.horzcat(d, ca.repmat(e, 1, pad)) for d, e in zip(data, last)]
    else:
        padded = data
    block = summed(size, "block")
    if threads > 1:
        outer = block.map(f"{name}_blocks", "thread", n_blocks, list(range(n_data, block.n_in())), all_out,
                          {"max_num_threads": threads})
    else:
        outer = block.map(f"{name}_blocks", "serial", n_blocks, list(range(n_data, block.n_in())), all_out)
    sums = as_list(outer(*(padded + rest)))
    if pad:
        extra = as_list(per_sample(*(last + rest)))
        sums = [a - pad * b for a, b in zip(sums, extra)]
    return ca.Function(name, data + rest, sums)


class MLSums:
    """The ML cost J/N of Eq. 6, its gradient and its Hessian as sums over samples.

    Decision vector ``w = [s; rho]`` with ``theta = scale * s`` (physical parameters
    scaled to order one) and ``rho = ln R``. Every function takes ``(w, X, Z)`` with the
    signals ``X`` (n_signals x N) and outputs ``Z`` (n_outputs x N).

    Attributes
    ----------
    cost : casadi.Function
        ``(w, X, Z) -> J/N``.
    gradient : casadi.Function
        ``(w, X, Z) -> (J/N, dJ/dw / N)``.
    hessian : casadi.Function
        ``(w, X, Z) -> triu(d2J/dw2) / N`` (upper triangle, sparse).
    per_sample_cost : casadi.Function
        ``(x, z, w) -> f``: one sample's term of J (SX), the function the sums map.
    """

    def __init__(self, model: Model, n_samples: int, scale: np.ndarray, threads: int = 1, jit: bool = False,
                 jit_flags=("-O2",), masked: bool = False, full_noise: bool = False):
        self.n_samples = N = n_samples
        ny = model.n_outputs
        if full_noise:  # w = [s; log-Cholesky of R]
            f_i, g_i, h_i = _full_noise_functions(model, tuple(np.asarray(scale, dtype=float)))
            w = ca.MX.sym("w", model.n_parameters + n_cholesky(ny))
        else:
            f_i, g_i, h_i = _per_sample_functions(model, tuple(np.asarray(scale, dtype=float)), masked)
            w = ca.MX.sym("w", model.n_parameters + ny)
        X = ca.MX.sym("X", model.n_signals, N)
        Z = ca.MX.sym("Z", 2 * ny if masked else ny, N)
        cost = map_sum(f_i, N, threads, "ml_cost_sum", jit, jit_flags)(X, Z, w)
        value, grad = map_sum(g_i, N, threads, "ml_grad_sum", jit, jit_flags)(X, Z, w)
        hess = map_sum(h_i, N, threads, "ml_hess_sum", jit, jit_flags)(X, Z, w)
        self.per_sample_cost = f_i
        self.cost = ca.Function("ml_cost", [w, X, Z], [cost / N], ["w", "X", "Z"], ["f"])
        self.gradient = ca.Function("ml_gradient", [w, X, Z], [value / N, grad / N], ["w", "X", "Z"], ["f", "g"])
        self.hessian = ca.Function("ml_hessian", [w, X, Z], [hess / N], ["w", "X", "Z"], ["H"])


def symmetric(triu: ca.MX) -> ca.MX:
    """The full symmetric matrix from its upper triangle."""
    return triu + triu.T - ca.diag(ca.diag(triu))


_PER_SAMPLE = StructureCache()


def cholesky_factor(ell, ny: int):
    """Lower-triangular L from its log-Cholesky vector: ``ny`` log-diagonal entries, then the
    strictly lower entries column by column. ``L L'`` is the noise covariance (full R)."""
    L = ca.SX.zeros(ny, ny) if isinstance(ell, ca.SX) else ca.MX.zeros(ny, ny)
    k = ny
    for j in range(ny):
        L[j, j] = ca.exp(ell[j])
        for i in range(j + 1, ny):
            L[i, j] = ell[k]
            k += 1
    return L


def n_cholesky(ny: int) -> int:
    """Length of the log-Cholesky vector of an ny x ny covariance."""
    return ny * (ny + 1) // 2


def _full_noise_functions(model: Model, scale: tuple):
    """One sample's ML cost with a full unknown R = L L' in w = [s; ell] (log-Cholesky), and its derivatives.

    ``1/2 ||L^-1 (z - h)||^2 + sum_j ell_jj``: summed over N samples this is paper Eq. 6 with
    a full R (``N/2 ln|R|`` = N sum_j ell_jj).
    """
    key = (scale, "full")
    cache = _PER_SAMPLE.setdefault(model, {})
    if key not in cache:
        ny, n = model.n_outputs, model.n_parameters
        s = ca.SX.sym("s", n)
        ell = ca.SX.sym("ell", n_cholesky(ny))
        w = ca.vertcat(s, ell)
        z = ca.SX.sym("z", ny)
        h = ca.substitute(model.h, model.theta, s * ca.DM(np.asarray(scale)))
        L = cholesky_factor(ell, ny)
        r = z - h
        y = []  # forward substitution: L y = r
        for i in range(ny):
            acc = r[i]
            for j in range(i):
                acc = acc - L[i, j] * y[j]
            y.append(acc / L[i, i])
        f = 0.5 * ca.sumsqr(ca.vertcat(*y)) + ca.sum1(ell[:ny])
        names = ["x", "z", "w"]
        cache[key] = (
            ca.Function("mlf_cost_i", [model.x, z, w], [f], names, ["f"]),
            ca.Function("mlf_grad_i", [model.x, z, w], [f, ca.gradient(f, w)], names, ["f", "g"]),
            ca.Function("mlf_hess_i", [model.x, z, w], [ca.triu(ca.hessian(f, w)[0])], names, ["H"]),
        )
    return cache[key]


def _per_sample_functions(model: Model, scale: tuple, masked: bool = False):
    """One sample's ML cost, (cost, gradient) and triu(Hessian) in w = [s; rho]; cached per model.

    ``masked``: the sample's data are ``[z; m]`` with m = 1 for a measured output, 0 for a
    missing one; a missing output adds neither its residual nor its ln R_j (so each channel's
    ln R_j counts its own N_j).
    """
    key = (scale, masked)
    cache = _PER_SAMPLE.setdefault(model, {})
    if key not in cache:
        ny, n = model.n_outputs, model.n_parameters
        s = ca.SX.sym("s", n)
        rho = ca.SX.sym("rho", ny)
        w = ca.vertcat(s, rho)
        z = ca.SX.sym("z", 2 * ny if masked else ny)
        h = ca.substitute(model.h, model.theta, s * ca.DM(np.asarray(scale)))
        if masked:
            zz, m = z[:ny], z[ny:]
            f = 0.5 * ca.sum1(m * ca.exp(-rho) * (zz - h) ** 2) + 0.5 * ca.sum1(m * rho)
        else:
            f = 0.5 * ca.sum1(ca.exp(-rho) * (z - h) ** 2) + 0.5 * ca.sum1(rho)
        names = ["x", "z", "w"]
        f_i = ca.Function("ml_cost_i", [model.x, z, w], [f], names, ["f"])
        g_i = ca.Function("ml_grad_i", [model.x, z, w], [f, ca.gradient(f, w)], names, ["f", "g"])
        h_i = ca.Function("ml_hess_i", [model.x, z, w], [ca.triu(ca.hessian(f, w)[0])], names, ["H"])
        cache[key] = (f_i, g_i, h_i)
    return cache[key]


def per_sample_cost(model: Model, masked: bool = False, full_noise: bool = False) -> ca.Function:
    """One sample's term of J, ``(x, z, w) -> f`` with ``w = [theta; noise vector]`` (physical theta).

    The noise vector is ``ln R`` (diagonal R) or the log-Cholesky vector of a full R
    (``full_noise``); ``masked``: z is ``[z; m]`` (see :func:`_per_sample_functions`). The
    function every sum of this module maps.
    """
    scale = tuple(np.ones(model.n_parameters))
    functions = _full_noise_functions(model, scale) if full_noise else _per_sample_functions(model, scale, masked)
    return functions[0]


_SUMS = StructureCache()


def ml_sums(model: Model, n_samples: int, scale=None, threads: int | None = None, jit: bool = False,
            jit_flags=("-O2",), masked: bool = False, full_noise: bool = False) -> MLSums:
    """Cached :class:`MLSums` for (model, N, scale, threads, jit).

    Parameters
    ----------
    scale : array_like, shape (n_parameters,), optional
        Parameter scales (default ``model.scales``; pass ones for physical theta).
    threads : int, optional
        Default :func:`default_threads`.
    masked : bool
        The data carry an observation mask (missing outputs), see :func:`_per_sample_functions`.
    full_noise : bool
        R full and unknown, log-Cholesky parametrised (see :func:`cholesky_factor`).
    """
    scale = tuple(np.asarray(model.scales if scale is None else scale, dtype=float))
    threads = default_threads(n_samples) if threads is None else int(threads)
    key = (n_samples, scale, threads, bool(jit), tuple(jit_flags), bool(masked), bool(full_noise))
    cache = _SUMS.setdefault(model, {})
    if key not in cache:
        cache[key] = MLSums(model, n_samples, np.array(scale), threads, jit, jit_flags, masked, full_noise)
    return cache[key]


_JACOBIAN_MAPS = StructureCache()


def prediction_and_jacobian(model: Model, signals: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """h and d h / d theta at every sample, sample-major (the rows of one sample together).

    Parameters
    ----------
    signals : ndarray, shape (N, n_signals)
    theta : ndarray, shape (n_parameters,)

    Returns
    -------
    h : ndarray, shape (N * n_outputs,)
    J : ndarray, shape (N * n_outputs, n_parameters)
    """
    N = signals.shape[0]
    maps = _JACOBIAN_MAPS.setdefault(model, {})
    if N not in maps:
        maps[N] = model.jacobian_function.map(N)
    h, J = maps[N](signals.T, theta)
    ny, n = model.n_outputs, model.n_parameters
    return np.asarray(h).T.reshape(-1), np.asarray(J).reshape(ny, N, n).transpose(1, 0, 2).reshape(-1, n)


def residual_jacobian(model: Model, data, theta: np.ndarray) -> np.ndarray:
    """d h / d theta for all samples, shape (N * n_outputs, n_parameters), sample-major."""
    return prediction_and_jacobian(model, data.signals, theta)[1]
