"""Filter and smoother passes over a whole record as compiled CasADi recursions.

The step-by-step filters of :mod:`casest.filters.ekf` run one sample at a time from
Python (the online API). Over a recorded run the same equations are one symbolic step,
``(prior, sample) -> (next prior, what the sample records)``, repeated with CasADi's
``mapaccum`` so that the loop over the samples runs in C++ and the step itself in compiled
C. For records of at least ``SolverSettings.jit_min_samples`` samples the whole pass is one C
function (:class:`casest._casadi.record_loop.RecordLoop`: the step's generated C called in a C
loop, each sample's outputs written in place), compiled once through the compile cache;
shorter records, or a machine without a C compiler, run the ``mapaccum`` in CasADi's virtual
machine.

Missing measurements are masked inside the step, exactly: a channel that is not measured has
its row of the measurement Jacobian and its innovation set to zero and its noise variance to
one, uncoupled from the others, so that the gain has a zero column for it, the innovation
covariance is block diagonal with an identity block for it (``ln det S`` is that of the
measured channels) and the update is the one of the measured channels alone (summary Eq.
2.8-2.10 restricted to them). The iterated update (Eq. 3.15-3.18) is unrolled to its
iteration limit; after the stop of Eq. 3.16 the iterate is held, as the step-by-step loop
breaks.
"""

from __future__ import annotations

import weakref

import casadi as ca
import numpy as np

from .._casadi.memory import StructureCache
from .._casadi.numerics import compile_function
from .._casadi.record_loop import RecordLoop, RecordRows
from .._casadi.symbolic_algebra import ldl_solver, symmetric_product
from ..backend.ipopt import SolverSettings
from ..data.dataset import Dataset
from ..models import OptionError
from ..models.dynamic import DynamicModel

__all__ = ["compiled_pass_applies", "ekf_pass", "ekf_sample_function", "kf_pass", "rts_pass", "singular_innovation",
           "check_likelihood", "mark_missing", "square_matrices", "chunked_record_function", "run_chunks", "run_record",
           "record_columns", "filter_rows"]

_PASS_STEPS = StructureCache()

LOG_2PI = float(np.log(2.0 * np.pi))


def compiled_pass_applies(model: DynamicModel) -> bool:
    """Whether the model's integration step is symbolic (SX: RK4), so that the pass can be built
    and compiled; a CVODES step runs step by step."""
    step = model.step_function
    symbolic = _SYMBOLIC_STEPS.get(step)
    if symbolic is None:
        symbolic = _SYMBOLIC_STEPS[step] = step.is_a("SXFunction")
    return symbolic


#: step Function -> whether it is symbolic (``is_a`` takes microseconds, which a short record's pass feels)
_SYMBOLIC_STEPS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def singular_innovation(sample: int | None = None) -> OptionError:
    """The error of a singular innovation covariance (the step-by-step filters raise it too)."""
    where = "" if sample is None else f" at sample {sample}"
    return OptionError(f"the innovation covariance C P C' + R is singular or not finite{where}: either the state is "
                       "known exactly (P = 0) in a measured direction and R gives the measurements no noise (give a "
                       "positive definite R or a positive P0), or the covariances overflow (variances near 1e150 or "
                       "a diverging state: express them in larger units, check Q, R and the model)")


#: [SolverSettings, its default instance]: the record-loop choice's settings built once per class
_DEFAULTS: list = []


def _default_settings() -> SolverSettings:
    """``SolverSettings()``, built once (a short record's pass costs microseconds; the class is looked
    up at each call, so a caller that stands another in is followed)."""
    if not _DEFAULTS or _DEFAULTS[0] is not SolverSettings:
        _DEFAULTS[:] = [SolverSettings, SolverSettings()]
    return _DEFAULTS[1]


def check_likelihood(ll: np.ndarray) -> float:
    """The log-likelihood's terms summed; raise :func:`singular_innovation` at the first sample
    whose term is not finite.

    Parameters
    ----------
    ll : ndarray, shape (N, 1) or (N,)
        Each sample's term.

    Returns
    -------
    float
        Their sum.
    """
    total = float(ll.sum())  # not finite exactly when a term is not (the terms are far below overflow)
    if not np.isfinite(total):
        bad = ~np.isfinite(ll.reshape(-1))
        if bad.any():
            raise singular_innovation(int(np.flatnonzero(bad)[0]))
    return total


def mark_missing(e: np.ndarray, seen: np.ndarray) -> None:
    """Set the innovations of the channels not measured (``seen`` False) to NaN, in place."""
    if not seen.all():
        e[~seen] = np.nan


def _masked_update(prior, P, y, m, h, H, R):
    """The Joseph-form update with the measured channels (mask ``m``) only; returns x, P, e, ll and
    the innovation covariance of all channels, ``H P H' + R``."""
    n = prior.numel()
    HP = ca.mtimes(H, P)
    S_full = symmetric_product(H, P) + R
    M = ca.diag(m)
    e = m * (y - h)
    Rm = ca.mtimes([M, R, M]) + ca.diag(1 - m)
    S = ca.mtimes([M, S_full, M]) + ca.diag(1 - m)  # the measured channels; 1 on the others' diagonal
    solve, quadratic, logdet, _ = ldl_solver(S)
    K = solve(ca.mtimes(M, HP)).T
    x = prior + ca.mtimes(K, e)
    I_KH = ca.SX.eye(n) - ca.mtimes(K, ca.mtimes(M, H))
    P_new = symmetric_product(I_KH, P) + symmetric_product(K, Rm)
    ll = -0.5 * (quadratic(e) + logdet + ca.sum1(m) * LOG_2PI)
    return x, P_new, e, ll, S_full


def _ekf_step(model: DynamicModel, propagate, measure, iterated: bool, tol: float, max_iterations: int) -> ca.Function:
    """``(x(k|k-1), vec P(k|k-1), d_k, c) -> ([x; vec P](k+1|k), record_k)`` with
    ``d_k = [y_k (NaN as 0); mask; u_k; u_a; u_b; dt]`` and ``c = [theta; vec Qc; input noise; vec R]``;
    ``record_k = [x(k|k); vec P(k|k); e; vec S; ll; iterations; vec Phi]``."""
    n, ny, nu, npar = model.n_states, model.n_outputs, len(model.inputs), model.n_parameters
    nuk = model.step_function.size1_in(1)
    acc, d = ca.SX.sym("acc", n + n * n), ca.SX.sym("d", 2 * ny + nu + 2 * nuk + 1)
    c = ca.SX.sym("c", npar + n * n + nu + ny * ny)
    prior, P = acc[:n], ca.reshape(acc[n:], n, n)
    y, m, u, ua, ub, dt = ca.vertsplit(d, np.cumsum([0, ny, ny, nu, nuk, nuk, 1]).tolist())
    theta, Qc, su, R = ca.vertsplit(c, np.cumsum([0, npar, n * n, nu, ny * ny]).tolist())
    Qc, R = ca.reshape(Qc, n, n), ca.reshape(R, ny, ny)
    h, H = measure(prior, u, theta)
    x, P_post, e, ll, S_full = _masked_update(prior, P, y, m, h, H, R)
    measured = ca.sum1(m) > 0
    iterations = ca.if_else(measured, 1, 0)
    if iterated:
        x, P_post, iterations = _iterated(prior, P, y, m, u, theta, R, measure, tol, max_iterations, measured)
    x_next, P_next, Phi = propagate(x, P_post, ua, ub, dt, theta, Qc, u, su)
    record = ca.vertcat(x, ca.vec(P_post), e, ca.vec(S_full), ll, iterations, ca.vec(Phi))
    return ca.Function("ekf_sample", [acc, d, c], [ca.vertcat(x_next, ca.vec(P_next)), record],
                       ["acc", "d", "c"], ["acc_next", "record"])


def _iterated(prior, P, y, m, u, theta, R, measure, tol: float, max_iterations: int, measured):
    """Eq. 3.15-3.18 unrolled: the iterate is held once the relative change is at most ``tol``."""
    eta, done, count = prior, ca.SX(0), ca.SX(0)
    for i in range(max_iterations):
        h_i, H_i = measure(eta, u, theta)
        new, _, _, _, _ = _masked_update(prior, P, y, m, h_i + ca.mtimes(H_i, prior - eta), H_i, R)
        change = ca.norm_2(new - eta) / ca.fmax(ca.norm_2(eta), 1e-300)
        eta = ca.if_else(done, eta, new)
        count = ca.if_else(done, count, i + 1)
        done = ca.logic_or(done, change <= tol)
    h_l, H_l = measure(eta, u, theta)
    _, P_post, _, _, _ = _masked_update(prior, P, y, m, h_l + ca.mtimes(H_l, prior - eta), H_l, R)
    x = ca.if_else(measured, eta, prior)
    return x, ca.if_else(measured, P_post, P), ca.if_else(measured, count, 0)


def ekf_pass(ekf, data: Dataset, x0: np.ndarray, out: tuple | None = None) -> dict:
    """The EKF (or IEKF) of ``ekf`` over ``data`` from ``x0`` and ``ekf.P0`` in one compiled recursion.

    Parameters
    ----------
    ekf : casest.filters.ekf.ExtendedKalmanFilter
    data : Dataset
        The model's record (time, inputs, outputs; NaN outputs are missing).
    x0 : ndarray, shape (n_states,)
    out : tuple, optional
        The ``buffers`` of an earlier pass's result over a record of the same length, written
        into (:func:`run_record`).

    Returns
    -------
    dict
        The arrays of :class:`casest.filters.ekf.FilterResult` by field name, as the
        step-by-step :meth:`ExtendedKalmanFilter.filter` records them, and ``buffers``.
    """
    model, N = ekf.model, data.n_samples
    n, ny = model.n_states, model.n_outputs
    step = ekf_sample_function(ekf)
    D, seen = filter_rows(model, data)
    c = np.concatenate([ekf.theta, ekf.Qc.reshape(-1, order="F"), ekf.input_noise, ekf.R.reshape(-1, order="F")])
    acc0 = np.concatenate([x0, ekf.P0.reshape(-1, order="F")])
    accs, fields = run_record(step, acc0, D, c, compiled=_default_settings().record_loop(N),
                              widths=(n, n * n, ny, ny * ny, 1, 1, n * n), out=out)
    xf, Pf, e, S, ll, its, Phi = fields
    priors = accs[:-1]
    log_likelihood = check_likelihood(ll)
    mark_missing(e, seen)
    return dict(x_predicted=priors[:, :n], P_predicted=square_matrices(priors[:, n:], n), x_filtered=xf,
                P_filtered=square_matrices(Pf, n), transition=square_matrices(Phi[:-1], n), innovation=e,
                innovation_covariance=square_matrices(S, ny), iterations=its[:, 0].astype(int),
                log_likelihood=log_likelihood, buffers=(accs, fields))


def filter_rows(model: DynamicModel, data: Dataset) -> tuple[np.ndarray | RecordRows, np.ndarray]:
    """What a nonlinear filter's pass reads per sample: the record itself (:class:`RecordRows`,
    whose rows the compiled loop builds) where the model's intervals take the inputs at their ends
    (every input hold but the cubic), else :func:`record_columns`; and the mask of measured channels.

    Parameters
    ----------
    model : DynamicModel
    data : Dataset

    Returns
    -------
    D : RecordRows or ndarray, shape (N, 2 n_outputs + n_inputs + 2 n_step_inputs + 1)
    seen : ndarray of bool, shape (N, n_outputs)
    """
    if model.input_hold == "cubic":
        return record_columns(model, data)
    return RecordRows(data.outputs, data.signals), np.isfinite(data.outputs)


def record_columns(model: DynamicModel, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
    """The per-sample rows a nonlinear filter's pass reads, ``[y (NaN as 0); mask; u; u_a; u_b; dt]``
    (the last sample's step of length zero), and the mask of measured channels.

    Parameters
    ----------
    model : DynamicModel
    data : Dataset

    Returns
    -------
    D : ndarray, shape (N, 2 n_outputs + n_inputs + 2 n_step_inputs + 1)
    seen : ndarray of bool, shape (N, n_outputs)
    """
    N = data.n_samples
    t, U, Y = data.signals[:, 0], data.signals[:, 1:], data.outputs
    seen = np.isfinite(Y)
    ny, nu, nuk = Y.shape[1], U.shape[1], model.step_function.size1_in(1)
    # every column written in place into one array (no intermediate copies of the record), each entry once
    D = np.empty((N, 2 * ny + nu + 2 * nuk + 1))
    if seen.all():
        D[:, :ny] = Y
        D[:, ny:2 * ny] = 1.0
    else:
        np.copyto(D[:, :ny], np.where(seen, Y, 0.0))
        D[:, ny:2 * ny] = seen
    D[:, 2 * ny:2 * ny + nu] = U
    a = 2 * ny + nu
    D[N - 1:, a:] = 0.0  # the last sample's step (none in an empty record)
    if N > 1:
        D[:-1, a:a + nuk], D[:-1, a + nuk:a + 2 * nuk] = model.interval_input_values(U)
        np.subtract(t[1:], t[:-1], out=D[:-1, -1])
    return D, seen


def square_matrices(a: np.ndarray, k: int) -> np.ndarray:
    """Per-sample column-major vectors of k x k matrices, shape (N, k*k), as matrices (N, k, k)."""
    return a.reshape(-1, k, k).transpose(0, 2, 1)


def ekf_sample_function(ekf) -> ca.Function:
    """The EKF step of the filter's model and options (cached on the model): the one sample of
    its compiled pass, and of its C export (:func:`casest.export.filter_c.export_c`).

    Parameters
    ----------
    ekf : casest.ExtendedKalmanFilter

    Returns
    -------
    casadi.Function
        ``(acc, d, c) -> (acc_next, record)`` (see :func:`_ekf_step`).
    """
    key = ("pass_step", ekf.iterated, ekf.tol, ekf.max_iterations)
    kept = _FILTER_STEPS.get(ekf)  # this filter's last answer: the shared cache's lookup takes microseconds
    if kept is not None and kept[0] is ekf.model and kept[1] == key:
        return kept[2]
    cache = _PASS_STEPS.setdefault(ekf.model, {})
    if key not in cache:
        cache[key] = _ekf_step(ekf.model, ekf._propagate, ekf._measure, ekf.iterated, ekf.tol, ekf.max_iterations)
    _FILTER_STEPS[ekf] = (ekf.model, key, cache[key])
    return cache[key]


#: filter -> (its model, the step's options, the step) of its last pass
_FILTER_STEPS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def kf_pass(kf, Y: np.ndarray, U: np.ndarray, matrices: tuple) -> dict:
    """The linear Kalman filter of ``kf`` over a record from its current state, as one recursion.

    Parameters
    ----------
    kf : casest.filters.kalman.KalmanFilter
    Y : ndarray, shape (N, q)
        Measurements (NaN: missing channel).
    U : ndarray, shape (N, m)
        Inputs.
    matrices : (Phi, C, Psi, Gamma Q Gamma', R, D)
        The record's matrices, shapes (N-1, n, n), (N, q, n), (N-1, n, m), (N-1, n, n),
        (N, q, q) and (N, q, m) (:meth:`KalmanFilter.matrices`); constant ones enter the step
        as constants.

    Returns
    -------
    dict
        The arrays of :class:`casest.filters.filter_records.FilterResult` by field name, as
        :meth:`KalmanFilter.filter` step by step records them.
    """
    N, (n, q, m) = Y.shape[0], (kf.n_states, kf.n_outputs, kf.n_inputs)
    Phis, Cs, Psis, GQGs, Rs, Ds = matrices
    varying = kf.time_varying
    step = _kf_step(n, q, m, varying)
    seen = np.isfinite(Y)
    columns = [np.where(seen, Y, 0.0), seen.astype(float), U]
    if varying:  # the matrices of each sample ride with its data (the last sample's transition is never used)
        pad = lambda A: np.concatenate([A, np.zeros((1,) + A.shape[1:])]) if len(A) < N else A
        columns += [_vec_rows(A) for A in (pad(Phis), Cs, pad(GQGs), Rs, pad(Psis), Ds)]
        fixed = ()
    else:
        fixed = (kf.Phi, kf.C, kf.Gamma @ kf.Q @ kf.Gamma.T, kf.R, kf.Psi, kf.D)
    D = np.hstack(columns)
    c = np.concatenate([a.reshape(-1, order="F") for a in fixed]) if fixed else np.zeros(0)
    acc0 = np.concatenate([kf.x, kf.P.reshape(-1, order="F")])
    accs, (xf, Pf, e, S, ll) = run_record(step, acc0, D, c, compiled=_default_settings().record_loop(N),
                                          widths=(n, n * n, q, q * q, 1))
    priors = accs[:-1]
    log_likelihood = check_likelihood(ll)
    mark_missing(e, seen)
    return dict(x_predicted=priors[:, :n], P_predicted=square_matrices(priors[:, n:], n), x_filtered=xf,
                P_filtered=square_matrices(Pf, n), transition=np.array(Phis[:max(N - 1, 0)]),
                innovation=e, innovation_covariance=square_matrices(S, q),
                iterations=seen.any(axis=1).astype(int), log_likelihood=log_likelihood)


def _vec_rows(A: np.ndarray) -> np.ndarray:
    """Each matrix of a (K, r, c) stack as a column-major row, shape (K, r c)."""
    return A.transpose(0, 2, 1).reshape(A.shape[0], -1)


def _kf_step(n: int, q: int, m: int, varying: bool = False) -> ca.Function:
    """``([x; vec P](k|k-1), d, c) -> ([x; vec P](k+1|k), [x; vec P](k|k), e, vec S, ll)`` (cached by
    dimensions). Constant matrices: ``d = [y; mask; u]``, ``c = [vec Phi; vec C; vec Gamma Q Gamma';
    vec R; vec Psi; vec D]``; time-varying: every matrix of the sample rides in ``d`` after
    ``[y; mask; u]`` in that order, and ``c`` is empty."""
    key = (n, q, m, varying)
    if key not in _KF_STEPS:
        acc = ca.SX.sym("acc", n + n * n)
        shapes = [(n, n), (q, n), (n, n), (q, q), (n, m), (q, m)]
        d = ca.SX.sym("d", 2 * q + m + (sum(a * b for a, b in shapes) if varying else 0))
        c = ca.SX.sym("c", 0 if varying else sum(a * b for a, b in shapes))
        x, P = acc[:n], ca.reshape(acc[n:], n, n)
        y, mask, u, rest = ca.vertsplit(d, [0, q, 2 * q, 2 * q + m, d.numel()])
        Phi, C, GQG, R, Psi, Dm = _unpack(rest if varying else c, shapes)
        x_post, P_post, e, ll, S_full = _masked_update(x, P, y, mask, ca.mtimes(C, x) + ca.mtimes(Dm, u), C, R)
        x_next = ca.mtimes(Phi, x_post) + ca.mtimes(Psi, u)
        P_next = symmetric_product(Phi, P_post) + GQG
        record = ca.vertcat(x_post, ca.vec(P_post), e, ca.vec(S_full), ll)
        _KF_STEPS[key] = ca.Function("kf_sample" + ("_varying" if varying else ""), [acc, d, c],
                                     [ca.vertcat(x_next, ca.vec(P_next)), record], ["acc", "d", "c"],
                                     ["acc_next", "record"])
    return _KF_STEPS[key]


def _unpack(v, shapes) -> list:
    """The column-major matrices of ``shapes`` stacked in the vector ``v``."""
    offsets = np.cumsum([0] + [a * b for a, b in shapes]).tolist()
    if v.numel() == 0:
        return [ca.SX(a, b) for a, b in shapes]
    return [ca.reshape(part, *shape) for part, shape in zip(ca.vertsplit(v, offsets), shapes)]


_KF_STEPS: dict = {}


#: samples per call of a pass: the recursion is built once for this many (building CasADi's
#: mapaccum for a whole record of 1e4 samples takes 0.36 s, longer than running it), and a
#: record runs as consecutive chunks, the last padded with samples that change nothing
CHUNK = 256


def chunked_record_function(step: ca.Function) -> ca.Function:
    """``(acc0, D (n_d x CHUNK), c) -> (accumulators, records)``: the step repeated over a chunk (cached)."""
    cached = _CHUNKED.get(id(step))
    if cached is not None and cached[0] is step:
        return cached[1]
    acc0, D = ca.MX.sym("acc0", step.size1_in(0)), ca.MX.sym("D", step.size1_in(1), CHUNK)
    c = [ca.MX.sym("c", step.size1_in(2))] if step.n_in() > 2 else []
    outs = step.mapaccum(f"{step.name()}_chunk", CHUNK)(acc0, D, *[ca.repmat(v, 1, CHUNK) for v in c])
    run = ca.Function(f"{step.name()}_record", [acc0, D] + c, list(outs) if isinstance(outs, (list, tuple)) else [outs])
    _CHUNKED[id(step)] = (step, run)
    return run


_CHUNKED: dict = {}


def run_chunks(run: ca.Function, acc0: np.ndarray, D: np.ndarray, *constants) -> tuple:
    """The accumulators after every sample, shape (N, n_acc), and the records, shape (N, n_record)
    (none for a step without records), running ``run`` over consecutive chunks of the rows of ``D``;
    the padding rows are zeros (no measurement, a step of zero length)."""
    N = D.shape[0]
    accs, records, acc = [], [], acc0
    for start in range(0, N, CHUNK):
        block = D[start:start + CHUNK]
        L = block.shape[0]
        if L < CHUNK:
            block = np.vstack([block, np.zeros((CHUNK - L, D.shape[1]))])
        outs = run(acc, block.T, *constants)
        outs = outs if isinstance(outs, (list, tuple)) else [outs]
        chunk_accs = np.asarray(outs[0])[:, :L].T
        accs.append(chunk_accs)
        if len(outs) > 1:
            records.append(np.asarray(outs[1])[:, :L].T)
        acc = chunk_accs[-1]
    return np.vstack(accs), (np.vstack(records) if records else None)


def run_record(step: ca.Function, acc0: np.ndarray, D: np.ndarray | RecordRows, *constants, compiled: bool | None,
               widths=(), out: tuple | None = None) -> tuple:
    """``step`` over the rows of ``D`` from ``acc0``: the accumulators before and after every
    sample and the fields of every sample's record.

    Parameters
    ----------
    step : casadi.Function
        ``(acc, d[, c]) -> (acc_next[, record])``.
    acc0 : ndarray, shape (n_acc,)
    D : ndarray, shape (N, n_d), or RecordRows
        The rows, or a filter's record whose rows the compiled loop builds itself (the other
        paths build them in NumPy: :meth:`RecordRows.columns`).
    *constants : ndarray
        The step's constant input ``c``, if it has one.
    compiled : bool or None
        True: one compiled C loop over the record (:class:`~casest._casadi.record_loop.RecordLoop`,
        built once per step), which writes every field in place; None: that loop only where it is
        compiled already (this process or the compile cache: a short record then costs no
        compile), else CasADi's ``mapaccum`` over chunks; False: the ``mapaccum`` (as without a
        compiler); :meth:`casest.SolverSettings.record_loop` chooses.
    widths : sequence of int
        The record's fields, in order (empty for a step without a record).
    out : (accs, fields), optional
        The arrays of an earlier run over a record of the same length, written into where the
        compiled loop runs (:meth:`RecordLoop.__call__`); the other paths make new arrays.

    Returns
    -------
    accs : ndarray, shape (N + 1, n_acc)
        ``acc0``, then the accumulator after each sample.
    fields : list of ndarray, shapes (N, width)
    """
    widths = tuple(int(w) for w in widths)
    signal_rows = (D.outputs.shape[1], D.signals.shape[1] - 1) if type(D) is RecordRows else None
    loop = _record_loop(step, widths, compiled, signal_rows) if compiled is not False else None
    if loop is not None:
        return loop(acc0, D, *constants) if out is None else loop(acc0, D, *constants, out=out)
    if signal_rows is not None:
        D = D.columns()
    if compiled:
        step = compile_function(step, ("-O2",))
    accs, records = run_chunks(chunked_record_function(step), acc0, D, *constants)
    offsets = np.cumsum((0,) + widths)
    fields = [np.ascontiguousarray(records[:, a:b]) for a, b in zip(offsets[:-1], offsets[1:])]
    return np.vstack([np.asarray(acc0, dtype=float)[None, :], accs]), fields


_LOOPS: dict = {}


def _record_loop(step: ca.Function, widths: tuple, compile_now: bool | None, signal_rows: tuple | None = None):
    """The step's compiled loop (building its rows from a record where ``signal_rows`` are given):
    built (``compile_now``), or only found where it exists already (None otherwise); each answer
    kept per step for this process."""
    key = (id(step), widths, signal_rows)
    cached = _LOOPS.get(key)
    if cached is None or cached[0] is not step or (cached[1] is None and compile_now and not cached[2]):
        loop = RecordLoop.build(step, widths if widths else None, cached_only=not compile_now, last_entry_first=True,
                                signal_rows=signal_rows)
        cached = _LOOPS[key] = (step, loop, bool(compile_now))
    return cached[1]


def rts_pass(result) -> tuple[np.ndarray, np.ndarray]:
    """The Rauch-Tung-Striebel smoother (Eq. 2.20, 2.22) of a filter pass as one recursion backwards.

    Parameters
    ----------
    result : FilterResult

    Returns
    -------
    x : ndarray, shape (N, n)
    P : ndarray, shape (N, n, n)
    """
    xf, Pf, xp, Pp, Phi = result.x_filtered, result.P_filtered, result.x_predicted, result.P_predicted, result.transition
    N, n = xf.shape
    if N < 2:
        return xf.copy(), Pf.copy()
    step = _rts_step(n)
    vec = lambda A: A.transpose(0, 2, 1).reshape(A.shape[0], -1)  # column-major per sample
    # backwards: sample k = N-2 ... 0 takes its filtered values, the prediction k+1 and Phi(k)
    D = np.hstack([xf[:-1], vec(Pf[:-1]), xp[1:], vec(Pp[1:]), vec(Phi)])[::-1]
    acc0 = np.concatenate([xf[-1], Pf[-1].reshape(-1, order="F")])
    accs, _ = run_record(step, acc0, D, compiled=_default_settings().record_loop(N))
    smoothed = accs[::-1]
    return smoothed[:, :n], smoothed[:, n:].reshape(N, n, n).transpose(0, 2, 1)


def _rts_step(n: int) -> ca.Function:
    """The RTS step for n states (cached)."""
    if n not in _RTS_STEPS:
        _RTS_STEPS[n] = _build_rts_step(n)
    return _RTS_STEPS[n]


_RTS_STEPS: dict = {}


def _build_rts_step(n: int) -> ca.Function:
    """``([x; vec P](k+1|N), [x(k|k); vec P(k|k); x(k+1|k); vec P(k+1|k); vec Phi(k)]) -> [x; vec P](k|N)``."""
    acc, d = ca.SX.sym("acc", n + n * n), ca.SX.sym("d", 2 * (n + n * n) + n * n)
    xs1, Ps1 = acc[:n], ca.reshape(acc[n:], n, n)
    xf, Pf, xp, Pp, Phi = ca.vertsplit(d, np.cumsum([0, n, n * n, n, n * n, n * n]).tolist())
    Pf, Pp, Phi = ca.reshape(Pf, n, n), ca.reshape(Pp, n, n), ca.reshape(Phi, n, n)
    C = ca.solve(Pp, ca.mtimes(Phi, Pf)).T
    xs = xf - ca.mtimes(C, xp - xs1)
    Ps = Pf - ca.mtimes([C, Pp - Ps1, C.T])
    return ca.Function("rts_sample", [acc, d], [ca.vertcat(xs, ca.vec(0.5 * (Ps + Ps.T)))])
