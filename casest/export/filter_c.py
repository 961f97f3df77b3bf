"""The online estimators as dependency-free C: a source file, a header and a README for a flight
computer, generated from the same symbolic model and verified against casest's own filter.

:func:`export_c` writes the EKF, iterated EKF or UKF of a :class:`casest.DynamicModel`: the
sample's step (measurement update of y(k), then the time update to k+1) is the CasADi Function of
casest's compiled filter pass (:meth:`~casest.filters.model_filter.ModelFilter.sample_function`),
generated as C by CasADi's code generator, wrapped in a C API whose memory is one caller-owned
struct of fixed size (no heap), needing only the C standard library and libm:

- ``NAME_init(f, x0, P0, theta, Qc, input_noise, R, gate)``: the filter's start, its constants
  (``input_noise`` the EKF's white noise on the inputs; NULL for none, unused by the UKF) and its
  innovation gate (0: none), each checked; ``NAME_state`` is x0 until the first step;
- ``NAME_step(f, y, measured, u, u_start, u_end, dt)``: one sample, computed into scratch and
  committed only when every check passes; the returned ``NAME_status_t`` says what failed, and
  one bad sample costs at most one update (:mod:`casest.export.filter_c_api`);
- ``NAME_state``, ``NAME_covariance`` (x(k|k), P(k|k), column-major), ``NAME_innovation``,
  ``NAME_innovation_covariance``, ``NAME_predicted_state`` / ``NAME_predicted_covariance``
  (x(k+1|k), P(k+1|k)), ``NAME_log_likelihood``.

The header states the struct's size, the generated code's work and the largest stack a call uses
(measured at export: :mod:`casest.export.c_memory`) and documents every call.
"""

from __future__ import annotations

import os

import casadi as ca

from .._casadi.symbolic_algebra import ldl_solver
from ..errors import OptionError
from ..filters.compiled_passes import LOG_2PI
from ..models.modelfile import slow_user_code_notice
from .c_files import c_prefix, write_c_files
from .c_kernel import generated_c
from .c_memory import stack_use
from .filter_c_api import WRAPPER_INCLUDES, FilterSizes, filter_api, filter_header
from ..options import CodePrecision, ExportedEstimator, check_option, choices

__all__ = ["export_c", "EXPORTED_ESTIMATORS", "filter_sizes", "PUBLIC_CALLS"]

#: the estimators :func:`export_c` writes
EXPORTED_ESTIMATORS = choices(ExportedEstimator)  # rls: casest.export.rls_c
#: the default largest step :func:`export_c` writes, in CasADi operations
MAX_EXPORT_INSTRUCTIONS = 2_000_000
#: the public calls of an exported filter (``NAME_`` + each)
PUBLIC_CALLS = ("init", "step", "state", "covariance", "innovation", "innovation_covariance", "predicted_state",
                "predicted_covariance", "log_likelihood")


def export_c(state_filter, out: str | os.PathLike, name: str | None = None,
             precision: CodePrecision = "double", force: bool = False,
             max_instructions: float = MAX_EXPORT_INSTRUCTIONS) -> dict:
    """Write the C source, header and README of an EKF, iterated EKF or UKF (module docstring).

    Parameters
    ----------
    state_filter : ExtendedKalmanFilter or UnscentedKalmanFilter
        The filter to export: its model, and its form (``iterated=True``: the IEKF, its ``tol`` and
        ``max_iterations`` unrolled into the step; the UKF with its sigma-point parameters). Its
        theta, noise and start are not built in: the C code takes them in ``NAME_init``.
    out : str or os.PathLike
        The folder (created if missing; the files written atomically, README.md keeping the
        sections of other exports: :mod:`casest.export.c_files`).
    name : str, optional
        The C prefix of every symbol (a C identifier; default ``casest_<model>_<ekf, iekf or ukf>``).
    precision : {"double", "single"}
        The C type of every number (``NAME_real``): double, or float for a flight computer without
        double-precision hardware (see the README written for what single precision costs).
    force : bool
        Replace files of the export's names that casest did not write.
    max_instructions : float
        The largest step exported, in CasADi operations (about 25 bytes of C each; the default
        :data:`MAX_EXPORT_INSTRUCTIONS` is about 48 MiB of C). Building the step is said on
        standard error after 10 s.

    Returns
    -------
    ExportedFiles
        ``{"source", "header", "readme"}``: the paths written; its ``replaced``: the files
        casest did not write that ``force`` replaced.

    Raises
    ------
    OptionError
        Not one of these filters, a name that is not a usable C prefix, a file in the way, or a
        step above ``max_instructions``.
    """
    from ..filters.ekf import ExtendedKalmanFilter
    from ..filters.unscented import UnscentedKalmanFilter

    if not isinstance(state_filter, (ExtendedKalmanFilter, UnscentedKalmanFilter)):
        raise OptionError(f"export_c takes a casest.ExtendedKalmanFilter (iterated or not) or a "
                          f"casest.UnscentedKalmanFilter, got {type(state_filter).__name__}")
    kind = "ukf" if isinstance(state_filter, UnscentedKalmanFilter) else ("iekf" if state_filter.iterated else "ekf")
    name = c_prefix(name, f"casest_{state_filter.model.name}_{kind}")
    check_option("precision", precision, CodePrecision)
    real = "float" if precision == "single" else "double"
    n = state_filter.model.n_states
    with slow_user_code_notice(f"building the {kind.upper()} step of {n} states for C",
                               advice=f"its time and C size grow about as n_states^2.3 (a chain of first-order "
                                      f"states: 40 states 0.6 s, 1.2 MB; 120: 9 s, 11 MB); steps above "
                                      f"{max_instructions:.0e} operations are refused"):
        step = _read_part(state_filter.sample_function(), state_filter.model)
    if step.n_instructions() > max_instructions:
        raise OptionError(f"the {kind.upper()} step of {n} states has {step.n_instructions()} operations (about "
                          f"{25 * step.n_instructions() / 2**20:.0f} MiB of C), more than max_instructions = "
                          f"{max_instructions:.0f}: a flight computer's code budget and the C compiler would not "
                          "take it; reduce the model (fewer states, sparser dynamics) or raise max_instructions")
    sizes = filter_sizes(state_filter.model, step)
    source = generated_c(step, name, real, WRAPPER_INCLUDES) + filter_api(name, sizes, real)
    stack = stack_use(source, filter_header(name, sizes, kind, state_filter.model.name, real, None), name,
                      tuple(f"{name}_{call}" for call in PUBLIC_CALLS))
    header = filter_header(name, sizes, kind, state_filter.model.name, real, stack)
    return write_c_files(out, name, header, source, _readme(name, sizes, kind, state_filter.model, real, stack), force)


def _read_part(step: ca.Function, model) -> ca.Function:
    """The step with its record cut to what the C API reads: x, P, e, S, and in place of the
    log-likelihood its terms without a logarithm, ``-(e' S^-1 e + m ln 2 pi) / 2`` and the
    pivots of the measured channels' ``S = L D L'`` (1 on an unmeasured channel), so that a step
    takes no logarithm (``NAME_log_likelihood`` takes them on request) and the wrapper checks
    that ``S`` is positive definite on the pivots. The transition and the iteration count are not
    computed in C where nothing else needs them. The terms are built from the record's own e and
    S the way the step builds them, and common subexpressions are merged (:func:`casadi.cse`), so
    the factorisation is computed once."""
    n, ny = model.n_states, model.n_outputs
    inputs = step.sx_in()
    acc_next, record = step.call(inputs)
    e_at, S_at = n + n * n, n + n * n + ny
    e, S = record[e_at:S_at], ca.reshape(record[S_at:S_at + ny * ny], ny, ny)
    mask = inputs[1][ny:2 * ny]  # d = [y; mask; ...]
    M = ca.diag(mask)
    _, quadratic, _, pivots = ldl_solver(ca.mtimes([M, S, M]) + ca.diag(1 - mask))
    base = -0.5 * (quadratic(e) + ca.sum1(mask) * LOG_2PI)
    return ca.Function(step.name(), inputs, ca.cse([acc_next, ca.vertcat(record[:S_at + ny * ny], base, pivots)]),
                       step.name_in(), step.name_out())


def filter_sizes(model, step: ca.Function) -> FilterSizes:
    """The sizes of an exported filter's arrays, from its model and its step Function.

    Parameters
    ----------
    model : DynamicModel
    step : casadi.Function
        ``(acc, d, c) -> (acc_next, record)``.

    Returns
    -------
    FilterSizes
    """
    n, ny, nu, npar = model.n_states, model.n_outputs, len(model.inputs), model.n_parameters
    return FilterSizes(n=n, ny=ny, nu=nu, nuk=model.step_function.size1_in(1), npar=npar,
                       input_noise=step.nnz_in(2) == npar + n * n + nu + ny * ny, acc=step.nnz_in(0),
                       d=step.nnz_in(1), c=step.nnz_in(2), record=step.nnz_out(1), w=step.sz_w(), iw=step.sz_iw(),
                       arg=step.sz_arg(), res=step.sz_res())


def _readme(name: str, s: FilterSizes, kind: str, model, real: str, stack: dict | None) -> str:
    precision = ("Every number is a `double` (`NAME_real`)." if real == "double" else
                 "Every number is a `float` (`NAME_real`), and the object holds no double arithmetic (float literals "
                 "and libm calls): single precision rounds at 6e-8 of a value. On casest's short-period example the "
                 "EKF's states stay within 3e-7 of their range of the double-precision filter's; a UKF with a small "
                 "alpha (sigma-point weights of order 1/alpha^2) loses its innovation covariance in float "
                 "(alpha = 1e-3: its update and then its prediction fail), with alpha = 1 it holds (5e-7). "
                 "Check the step's return value.").replace("NAME", name)
    up = name.upper()
    stack_text = (f"the largest stack a call uses, {stack['bytes']} bytes ({stack['function']}, {stack['compiler']})"
                  if stack else "the stack a call uses (not measured: no GCC at export)")
    return f"""# {name}

The {kind.upper()} of casest's model `{model.name}`, generated by `casest.export_c` as C99 that
needs only the C standard library and libm. **`{name}.h` documents every call**: its arguments,
sizes, return codes and what the state is after each failure.

- states ({s.n}): {", ".join(model.state_names)}
- outputs ({s.ny}): {", ".join(model.output_names)}
- inputs ({s.nu}): {", ".join(i.name for i in model.inputs) or "none"}; the step function reads {s.nuk} values at each
  end of an interval (`u_start`, `u_end`: the inputs at both ends for a linear hold)
- parameters ({s.npar}): {", ".join(model.parameter_names)}

Memory: one caller-owned `{name}_t` of `{up}_STRUCT_BYTES` bytes ({s.struct_bytes(4 if real == "float" else 8, 8)}
with 64-bit pointers, {s.struct_bytes(4 if real == "float" else 8, 4)} with 32-bit ones), no heap; declare it static or
global. The header also states `{up}_WORK_BYTES` and `{up}_STACK_BYTES`, {stack_text}.

Build: `cc -std=c99 -O2 -c {name}.c` (link with `-lm`); it compiles without a warning under
`-Wall -Wextra -Wpedantic -Wshadow -Wconversion -Wdouble-promotion` (gcc and clang, C99 and C11).

```c
static {name}_t f;
if ({name}_init(&f, x0, P0, theta, Qc, input_noise, R, 0) != {up}_OK) {{ /* an argument is wrong */ }}
for (k = 0; k < N; ++k) {{
  {name}_status_t status = {name}_step(&f, y_k, NULL, u_k, u_k, u_next, dt);  /* update, predict to k+1 */
  x = {name}_state(&f);   /* x(k|k): the last good one where status is not {up}_OK */
}}
```

A step is computed into scratch and committed only when every check passes: a NaN or infinite
measurement, an update that is not finite or a measurement beyond the gate drops that sample's
measurements and only predicts; a non-finite input or dt, or a failed evaluation, keeps the state.
The filter goes on at the next sample; `f.rejected` and `f.failed` count such steps. {precision}
"""
