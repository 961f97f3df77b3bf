"""The online estimators as dependency-free C: a source file, a header and a README for a flight
computer, generated from the same symbolic model and verified against casest's own filter.

:func:`export_c` writes the EKF, iterated EKF or UKF of a :class:`casest.DynamicModel`: the
sample's step (measurement update of y(k), then the time update to k+1) is the CasADi Function of
casest's compiled filter pass (:meth:`~casest.filters.model_filter.ModelFilter.sample_function`),
generated as C by CasADi's code generator, wrapped in a C API whose memory is one caller-owned
struct of fixed size (no heap), needing only the C standard library and libm:

- ``NAME_init(f, x0, P0, theta, Qc, input_noise, R)``: the filter's start and its constants
  (``input_noise`` the EKF's white noise on the inputs; NULL for none, unused by the UKF);
  returns 0, or 4 for an argument that is not finite, 5 for an R that is not symmetric positive
  definite, 6 for a P0 or Qc that is not symmetric positive semidefinite (the filter is not
  started); ``NAME_state`` is x0 until the first step;
- ``NAME_step(f, y, measured, u, u_start, u_end, dt)``: one sample (``measured`` may be NULL:
  then the channels whose y is finite); returns 0; 2 where the update failed (a singular
  innovation covariance, a corrupt sample): that sample's measurements are dropped and the
  state only predicted, so one bad sample costs one update, not the filter; 3 where the
  prediction failed too (a non-finite input or dt): the prediction is kept as it was
  (``NAME_predicted_state``; the sample's x(k|k) is not meaningful); 1 where the generated code
  failed;
- ``NAME_state``, ``NAME_covariance`` (x(k|k), P(k|k), column-major), ``NAME_innovation``,
  ``NAME_innovation_covariance``, ``NAME_predicted_state`` / ``NAME_predicted_covariance``
  (x(k+1|k), P(k+1|k)), ``NAME_log_likelihood``.
"""

from __future__ import annotations

import os
import re

import casadi as ca

from ..errors import OptionError
from ..models.modelfile import slow_user_code_notice
from .c_files import c_prefix, quiet_unused_parameters, write_c_files
from ..options import CodePrecision, ExportedEstimator, check_option, choices

__all__ = ["export_c", "EXPORTED_ESTIMATORS", "generated_c", "static_step_c"]

#: the estimators :func:`export_c` writes
EXPORTED_ESTIMATORS = choices(ExportedEstimator)  # rls: casest.export.rls_c
#: the default largest step :func:`export_c` writes, in CasADi operations
MAX_EXPORT_INSTRUCTIONS = 2_000_000


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
        step = state_filter.sample_function()
    if step.n_instructions() > max_instructions:
        raise OptionError(f"the {kind.upper()} step of {n} states has {step.n_instructions()} operations (about "
                          f"{25 * step.n_instructions() / 2**20:.0f} MiB of C), more than max_instructions = "
                          f"{max_instructions:.0f}: a flight computer's code budget and the C compiler would not "
                          "take it; reduce the model (fewer states, sparser dynamics) or raise max_instructions")
    sizes = _Sizes(state_filter.model, step)
    return write_c_files(out, name, _header(name, sizes, kind, real), generated_c(step, name, real) + _api(name, sizes, real),
                         _readme(name, sizes, kind, state_filter.model, real), force)


def static_step_c(name: str, nx: int, ny: int, n_acc: int) -> str:
    """The C of ``NAME_step(f, x, z, measured)`` for a recursive estimator of a static model whose
    sample Function is ``(acc, d = [x; z; mask], c) -> acc_next`` (the struct of its header).

    Parameters
    ----------
    name : str
        The C prefix.
    nx, ny : int
        Signals and outputs of a sample.
    n_acc : int
        The accumulator's size.

    Returns
    -------
    str
    """
    return f"""
int {name}_step({name}_t *f, const double *x, const double *z, const int *measured) {{
  int j;
  if ({nx} > 0) memcpy(f->d, x, {nx} * sizeof(double));
  for (j = 0; j < {ny}; ++j) {{
    int seen = measured ? measured[j] != 0 : isfinite(z[j]);
    f->d[{nx} + j] = seen ? z[j] : 0.0;
    f->d[{nx + ny} + j] = seen ? 1.0 : 0.0;
  }}
  f->arg[0] = f->acc;
  f->arg[1] = f->d;
  f->arg[2] = f->c;
  f->res[0] = f->acc_next;
  if ({name}_sample(f->arg, f->res, f->iw, f->w, 0)) return 1;
  memcpy(f->acc, f->acc_next, {n_acc} * sizeof(double));
  return 0;
}}
"""


class _Sizes:
    """The sizes of the exported filter's arrays."""

    def __init__(self, model, step: ca.Function):
        self.n, self.ny, self.nu = model.n_states, model.n_outputs, len(model.inputs)
        self.nuk = model.step_function.size1_in(1)
        self.npar = model.n_parameters
        self.input_noise = step.nnz_in(2) == self.npar + self.n * self.n + self.nu + self.ny * self.ny
        self.acc, self.d, self.c, self.record = (step.nnz_in(0), step.nnz_in(1), step.nnz_in(2), step.nnz_out(1))
        self.w, self.iw, self.arg, self.res = step.sz_w(), step.sz_iw(), step.sz_arg(), step.sz_res()
        self.state_names, self.output_names = tuple(model.state_names), tuple(model.output_names)
        self.input_names = tuple(s.name for s in model.inputs)
        self.parameter_names = tuple(model.parameter_names)


def generated_c(step: ca.Function, name: str, real: str = "double") -> str:
    """CasADi's C for a step Function, renamed ``NAME_sample``, after ``#include "NAME.h"``.

    Parameters
    ----------
    step : casadi.Function
        An SX Function.
    name : str
        The C prefix.
    real : {"double", "float"}
        The C type of every number.

    Returns
    -------
    str
        C99 text needing libm only (no heap: CasADi's work arrays are the caller's).
    """
    renamed = ca.Function(f"{name}_sample", step.sx_in(), step.call(step.sx_in()), step.name_in(), step.name_out())
    generator = ca.CodeGenerator(f"{name}_sample", {"with_header": False, "with_mem": False, "main": False,
                                                   "casadi_real": real, "casadi_int": "long long"})
    generator.add(renamed)
    text = quiet_unused_parameters(generator.dump())
    return f'#include "{name}.h"\n' + (in_single_precision(text) if real == "float" else text)


#: libm's double functions CasADi writes, and their float forms
FLOAT_FUNCTIONS = {f: f + "f" for f in ("sqrt", "log", "exp", "sin", "cos", "tan", "fabs", "pow", "atan2", "tanh",
                                        "atan", "asin", "acos", "sinh", "cosh", "log10", "erf", "floor", "ceil",
                                        "fmin", "fmax", "fmod", "log1p", "expm1", "asinh", "acosh", "atanh")}
_FLOAT_LITERAL = re.compile(r"(?<![\w.])((?:\d+\.\d*|\.\d+)(?:[eE][+-]?\d+)?|\d+[eE][+-]?\d+)(?![\w.])")
_DOUBLE_CALL = re.compile(r"\b(" + "|".join(sorted(FLOAT_FUNCTIONS, key=len, reverse=True)) + r")\(")


def in_single_precision(source: str) -> str:
    """CasADi's C with every floating literal a float (``2.f``; magnitudes below 1e-37 or above
    3e38 brought inside float's range) and every libm call its float form (``sqrtf``), so that
    single precision computes in float throughout (a double literal or call promotes the
    expression to double: on a Cortex-M4F a software operation).

    Parameters
    ----------
    source : str

    Returns
    -------
    str
    """
    return _DOUBLE_CALL.sub(lambda m: FLOAT_FUNCTIONS[m.group(1)] + "(", _FLOAT_LITERAL.sub(_float_literal, source))


def _float_literal(match: re.Match) -> str:
    """A double literal as a float one; magnitudes float cannot hold are brought to its range (a
    guard such as ``1e-300`` against a zero divisor would otherwise round to zero and guard nothing)."""
    value = abs(float(match.group(1)))
    if 0.0 < value < 1e-37:
        return "1e-37f"
    if value > 3e38:
        return "3e38f"
    return match.group(1) + "f"


def _header(name: str, s: _Sizes, kind: str, real: str = "double") -> str:
    guard = name.upper() + "_H"
    numbers = (4 if real == "float" else 8) * (2 * s.acc + s.c + s.d + s.record + max(s.w, 1) + max(s.n, s.ny) ** 2)
    size = numbers + 8 * max(s.iw, 1) + 8 * (max(s.arg, 1) + max(s.res, 1))
    size32 = numbers + 8 * max(s.iw, 1) + 4 * (max(s.arg, 1) + max(s.res, 1))
    macros = "\n".join(f"#define {name.upper()}_{key} {value}" for key, value in (
        ("N_STATES", s.n), ("N_OUTPUTS", s.ny), ("N_INPUTS", s.nu), ("N_STEP_INPUTS", s.nuk),
        ("N_PARAMETERS", s.npar)))
    return f"""/* {name}: the {kind.upper()} generated by casest from the model's symbolic form (see README.md). */
#ifndef {guard}
#define {guard}

{macros}

typedef {real} {name}_real;  /* the precision of every array and argument */

/* All the filter's memory: one caller-owned struct of fixed size ({size} bytes with 64-bit
   pointers, {size32} with 32-bit ones), no heap: declare it static or global rather than on a
   small task stack. */
typedef struct {{
  {name}_real acc[{s.acc}];        /* x(k|k-1) then P(k|k-1), column-major */
  {name}_real acc_next[{s.acc}];   /* x(k+1|k) then P(k+1|k) after a step */
  {name}_real c[{s.c}];            /* theta, Qc (column-major), input noise, R (column-major) */
  {name}_real d[{s.d}];            /* the sample: y, mask, u, u_start, u_end, dt */
  {name}_real record[{s.record}];  /* x(k|k), P(k|k), e, S, log-likelihood, iterations, Phi */
  {name}_real w[{max(s.w, 1)}];
  long long iw[{max(s.iw, 1)}];
  const {name}_real *arg[{max(s.arg, 1)}];
  {name}_real *res[{max(s.res, 1)}];
  {name}_real check[{max(s.n, s.ny) ** 2}];  /* init's factorisation of R, P0 and Qc */
}} {name}_t;

/* NAME_init returns 0, or: 4 an argument not finite, 5 R not symmetric positive definite,
   6 P0 or Qc not symmetric positive semidefinite (the filter is then not started). */
int {name}_init({name}_t *f, const {name}_real *x0, const {name}_real *P0, const {name}_real *theta, const {name}_real *Qc,
                const {name}_real *input_noise, const {name}_real *R);
/* NAME_step returns 0; 2: the measurement update failed (a singular innovation covariance, a
   corrupt sample): the sample's measurements were dropped and the state only predicted; 3: the
   prediction failed too (a non-finite input or dt): the prediction was kept; 1: the generated
   code failed. measured may be NULL (then the channels whose y is finite). */
int {name}_step({name}_t *f, const {name}_real *y, const int *measured, const {name}_real *u, const {name}_real *u_start,
                const {name}_real *u_end, {name}_real dt);
const {name}_real *{name}_state(const {name}_t *f);
const {name}_real *{name}_covariance(const {name}_t *f);
const {name}_real *{name}_innovation(const {name}_t *f);
const {name}_real *{name}_innovation_covariance(const {name}_t *f);
const {name}_real *{name}_predicted_state(const {name}_t *f);
const {name}_real *{name}_predicted_covariance(const {name}_t *f);
{name}_real {name}_log_likelihood(const {name}_t *f);

#endif
"""


def _api(name: str, s: _Sizes, real: str = "double") -> str:
    """The C API around the generated step: argument checks, init, the step, the accessors."""
    return _checks_c(name, real) + _init_c(name, s) + _step_c(name, s, real) + _accessors_c(name, s)


def _checks_c(name: str, real: str) -> str:
    """``NAME_finite`` and ``NAME_factorable`` (a Cholesky test), in the export's own precision."""
    single = real == "float"  # every literal and libm call in the export's own precision
    zero = "0.0f" if single else "0.0"
    tol, tiny = ("1e-6f", "1e-30f") if single else ("1e-9", "1e-300")
    sqrt, fabs = ("sqrtf", "fabsf") if single else ("sqrt", "fabs")
    return f"""
#include <math.h>
#include <string.h>

static int {name}_finite(const {name}_real *v, int n) {{
  int i;
  for (i = 0; i < n; ++i) if (!isfinite(v[i])) return 0;
  return 1;
}}

/* Whether A (m x m, column-major) is symmetric and positive definite, or, with semi, positive
   semidefinite: the Cholesky factorisation of A (A + 1e-6 max|A_ii| I with semi) in L, in the
   export's own precision. */
static int {name}_factorable({name}_real *L, const {name}_real *A, int m, int semi) {{
  int i, j, k;
  {name}_real big = {zero}, shift, d, v;
  for (i = 0; i < m; ++i) {{
    if (A[i + i * m] < {zero}) return 0;
    if (A[i + i * m] > big) big = A[i + i * m];
    for (j = 0; j < i; ++j)
      if ({fabs}(A[i + j * m] - A[j + i * m]) > {tol} * {fabs}(A[i + j * m]) + {tiny}) return 0;
  }}
  shift = semi ? {tol} * big + {tiny} : {zero};
  for (j = 0; j < m; ++j) {{
    d = A[j + j * m] + shift;
    for (k = 0; k < j; ++k) d -= L[j + k * m] * L[j + k * m];
    if (!(d > {zero})) return 0;
    L[j + j * m] = {sqrt}(d);
    for (i = j + 1; i < m; ++i) {{
      v = A[i + j * m];
      for (k = 0; k < j; ++k) v -= L[i + k * m] * L[j + k * m];
      L[i + j * m] = v / L[j + j * m];
    }}
  }}
  return 1;
}}

"""


def _init_c(name: str, s: _Sizes) -> str:
    """``NAME_init``: the arguments checked, then copied into the struct."""
    n, ny, nu = s.n, s.ny, s.nu
    noise_copy = (f"if ({nu} > 0 && input_noise) memcpy(f->c + {s.npar + n * n}, input_noise, {nu} * sizeof({name}_real));"
                  if s.input_noise else "(void)input_noise;  /* the UKF takes no input noise */")
    return f"""int {name}_init({name}_t *f, const {name}_real *x0, const {name}_real *P0, const {name}_real *theta, const {name}_real *Qc,
                const {name}_real *input_noise, const {name}_real *R) {{
  if (!{name}_finite(x0, {n}) || !{name}_finite(P0, {n * n}) || !{name}_finite(theta, {s.npar})
      || !{name}_finite(Qc, {n * n}) || !{name}_finite(R, {ny * ny})
      || ({nu} > 0 && {int(s.input_noise)} && input_noise && !{name}_finite(input_noise, {nu}))) return 4;
  if (!{name}_factorable(f->check, R, {ny}, 0)) return 5;
  if (!{name}_factorable(f->check, P0, {n}, 1) || !{name}_factorable(f->check, Qc, {n}, 1)) return 6;
  memset(f, 0, sizeof(*f));
  memcpy(f->acc, x0, {n} * sizeof({name}_real));
  memcpy(f->acc + {n}, P0, {n * n} * sizeof({name}_real));
  memcpy(f->record, x0, {n} * sizeof({name}_real));  /* NAME_state before the first step: x0 */
  memcpy(f->record + {n}, P0, {n * n} * sizeof({name}_real));
  memcpy(f->c, theta, {s.npar} * sizeof({name}_real));
  memcpy(f->c + {s.npar}, Qc, {n * n} * sizeof({name}_real));
  {noise_copy}
  memcpy(f->c + {s.npar + n * n + (nu if s.input_noise else 0)}, R, {ny * ny} * sizeof({name}_real));
  return 0;
}}

"""


def _step_c(name: str, s: _Sizes, real: str) -> str:
    """``NAME_step``: the sample in, the generated step, a failed update retried as a prediction."""
    n, ny, nu, nuk = s.n, s.ny, s.nu, s.nuk
    zero, one = ("0.0f", "1.0f") if real == "float" else ("0.0", "1.0")
    return f"""int {name}_step({name}_t *f, const {name}_real *y, const int *measured, const {name}_real *u, const {name}_real *u_start,
                const {name}_real *u_end, {name}_real dt) {{
  int j, flag;
  for (j = 0; j < {ny}; ++j) {{
    int seen = measured ? measured[j] != 0 : isfinite(y[j]);
    f->d[j] = seen ? y[j] : {zero};
    f->d[{ny} + j] = seen ? {one} : {zero};
  }}
  if ({nu} > 0) memcpy(f->d + {2 * ny}, u, {nu} * sizeof({name}_real));
  memcpy(f->d + {2 * ny + nu}, u_start, {nuk} * sizeof({name}_real));
  memcpy(f->d + {2 * ny + nu + nuk}, u_end ? u_end : u_start, {nuk} * sizeof({name}_real));
  f->d[{2 * ny + nu + 2 * nuk}] = dt;
  f->arg[0] = f->acc;
  f->arg[1] = f->d;
  f->arg[2] = f->c;
  f->res[0] = f->acc_next;
  f->res[1] = f->record;
  flag = {name}_sample(f->arg, f->res, f->iw, f->w, 0);
  if (flag) return 1;
  if (isfinite(f->record[{n + n * n + ny + ny * ny}]) && {name}_finite(f->acc_next, {s.acc})) {{
    memcpy(f->acc, f->acc_next, {s.acc} * sizeof({name}_real));
    return 0;
  }}
  /* the update failed: this sample's measurements are dropped (values too: 0 times inf is NaN) and the
     state only predicted */
  for (j = 0; j < {2 * ny}; ++j) f->d[j] = {zero};
  flag = {name}_sample(f->arg, f->res, f->iw, f->w, 0);
  if (flag == 0 && {name}_finite(f->acc_next, {s.acc})) {{
    memcpy(f->acc, f->acc_next, {s.acc} * sizeof({name}_real));
    return 2;
  }}
  return 3;  /* the prediction failed too (a non-finite input or dt): the state is kept as it was */
}}

"""


def _accessors_c(name: str, s: _Sizes) -> str:
    """The accessors of the struct's record and prediction."""
    n, ny = s.n, s.ny
    return f"""const {name}_real *{name}_state(const {name}_t *f) {{ return f->record; }}
const {name}_real *{name}_covariance(const {name}_t *f) {{ return f->record + {n}; }}
const {name}_real *{name}_innovation(const {name}_t *f) {{ return f->record + {n + n * n}; }}
const {name}_real *{name}_innovation_covariance(const {name}_t *f) {{ return f->record + {n + n * n + ny}; }}
const {name}_real *{name}_predicted_state(const {name}_t *f) {{ return f->acc; }}
const {name}_real *{name}_predicted_covariance(const {name}_t *f) {{ return f->acc + {n}; }}
{name}_real {name}_log_likelihood(const {name}_t *f) {{ return f->record[{n + n * n + ny + ny * ny}]; }}
"""


def _readme(name: str, s: _Sizes, kind: str, model, real: str = "double") -> str:
    precision = ("Every number is a `double` (`NAME_real`)." if real == "double" else
                 "Every number is a `float` (`NAME_real`): single precision rounds at 6e-8 of a value. On casest's "
                 "short-period example the EKF's states stay within 3e-7 of their range of the double-precision "
                 "filter's; a UKF with a small alpha (sigma-point weights of order 1/alpha^2) loses its innovation "
                 "covariance in float (alpha = 1e-3: its update and then its prediction fail, the step returns 3 at "
                 "sample 120), with alpha = 1 it holds (5e-7). "
                 "Check the step's return value.").replace("NAME", name)
    return f"""# {name}

The {kind.upper()} of casest's model `{model.name}`, generated by `casest.export_c` as C99 that
needs only the C standard library and libm. All memory is one caller-owned `{name}_t`
(`sizeof` fixed at compile time, no heap allocation).

- states ({s.n}): {", ".join(s.state_names)}
- outputs ({s.ny}): {", ".join(s.output_names)}
- inputs ({s.nu}): {", ".join(s.input_names) or "none"}; the step function reads {s.nuk} values at each
  end of an interval (`u_start`, `u_end`: the inputs at both ends for a linear hold)
- parameters ({s.npar}): {", ".join(s.parameter_names)}

Build: `cc -O2 -c {name}.c` (link with `-lm`).

```c
{name}_t f;
{name}_init(&f, x0, P0, theta, Qc, input_noise, R);  /* column-major matrices */
for (k = 0; k < N; ++k) {{
  {name}_step(&f, y_k, NULL, u_k, u_k, u_next, dt);  /* update with y_k, predict to k+1 */
  x = {name}_state(&f);                               /* x(k|k); P(k|k): {name}_covariance */
}}
```

`measured` (or NULL: the channels whose y is finite) marks the channels measured at the sample.
The step returns 0; 2 where the measurement update failed (a singular innovation covariance, a
corrupt sample): that sample's measurements are dropped and the state is only predicted, so the
filter goes on; 3 where the prediction failed too (a non-finite input or dt): the prediction is
kept as it was (`{name}_predicted_state`; that sample's `{name}_state` is not meaningful); 1 where
the generated code failed. {precision}
"""
