"""The C API an exported EKF, IEKF or UKF offers around its generated step: the header (sizes,
memory, status codes, every function documented in Doxygen form) and the wrapper's C.

Failure semantics of the step (a flight estimator must survive one bad sample):

- the step is evaluated into scratch (``acc_next``, ``record_next``) and committed only when every
  check passes, so a failed step leaves the last good state in place;
- a non-finite input, input at either end of the interval, or dt: nothing is evaluated, the state
  stays (``NON_FINITE_INPUT``);
- a channel marked measured whose value is not finite (``NON_FINITE_MEASUREMENT``), an update
  that is not finite (``UPDATE_FAILED``: the innovation covariance is not positive definite, or a
  value overflowed), or an innovation beyond the gate (``MEASUREMENT_REJECTED``): the sample's
  measurements are dropped and the state is only predicted, exactly as for a sample without
  measurements;
- the generated code failing, or a prediction that is not finite: the state stays
  (``EVALUATION_FAILED``).

The wrapper is written to MISRA C:2012's mandatory and required rules (checked with cppcheck's
addon: :mod:`casest.export.misra`), and compiles without a warning under
``-std=c99 -Wall -Wextra -Wpedantic -Wshadow -Wconversion -Wdouble-promotion``.
"""

from __future__ import annotations

from dataclasses import dataclass

from .c_common import (Member, cholesky_c, finite_c, literal, memory_macros_c, status_enum_c, struct_bytes,
                       struct_c, work_bytes)

__all__ = ["FilterSizes", "STATUS_CODES", "filter_header", "filter_api", "WRAPPER_INCLUDES"]

#: the standard headers the wrapper needs, included at the top of ``NAME.c`` (MISRA C rule 20.1)
WRAPPER_INCLUDES = "#include <math.h>\n#include <stdbool.h>\n#include <string.h>\n"

#: the status codes of ``NAME_init`` and ``NAME_step``: (enumerator suffix, value, meaning)
STATUS_CODES = (
    ("OK", 0, "the step (or init) succeeded"),
    ("EVALUATION_FAILED", 1, "the generated code failed or its prediction is not finite: the state was kept"),
    ("UPDATE_FAILED", 2, "the measurement update is not finite (an innovation covariance that is not positive "
                         "definite, or an overflow): the sample's measurements were dropped and the state predicted"),
    ("NON_FINITE_INPUT", 3, "an input, an interval-end input or dt is not finite: nothing was evaluated, the state "
                            "was kept"),
    ("INVALID_ARGUMENT", 4, "init: an argument is NULL or not finite, or the gate is negative (not started)"),
    ("R_NOT_POSITIVE_DEFINITE", 5, "init: R is not symmetric positive definite (not started)"),
    ("COVARIANCE_NOT_POSITIVE_SEMIDEFINITE", 6, "init: P0 or Qc is not symmetric positive semidefinite "
                                                "(not started)"),
    ("MEASUREMENT_REJECTED", 7, "the normalised innovation squared exceeded the gate: the sample's measurements "
                                "were dropped and the state predicted"),
    ("NON_FINITE_MEASUREMENT", 8, "a channel marked measured holds a NaN or an infinity: the sample's "
                                  "measurements were dropped and the state predicted"),
)


@dataclass(frozen=True)
class FilterSizes:
    """The sizes of an exported filter's arrays (numbers of values) and its names.

    Attributes
    ----------
    n, ny, nu, nuk, npar : int
        States, outputs, inputs, inputs the step reads at each end of an interval, parameters.
    input_noise : bool
        Whether the constants hold the EKF's input noise.
    acc, d, c, record : int
        The step's accumulator, sample, constants and record.
    w, iw, arg, res : int
        CasADi's work arrays.
    """

    n: int
    ny: int
    nu: int
    nuk: int
    npar: int
    input_noise: bool
    acc: int
    d: int
    c: int
    record: int
    w: int
    iw: int
    arg: int
    res: int

    @property
    def record_used(self) -> int:
        """The record's values the accessors read: x(k|k), P(k|k), e, S and the log-likelihood's
        terms (its part without a logarithm, then the innovation covariance's ny pivots)."""
        return self.pivots_at + self.ny

    @property
    def pivots_at(self) -> int:
        """Where the record's pivots of ``S = L D L'`` start (after the log-likelihood's part
        without a logarithm)."""
        return self.n + self.n * self.n + self.ny + self.ny * self.ny + 1

    def members(self) -> list:
        """The members of ``NAME_t`` in order (8-byte integers first, so that no padding falls
        between them on common targets).

        Returns
        -------
        list of Member
        """
        return [Member("long long", "iw", self.iw, "generated code's integer work"),
                Member("unsigned long long", "rejected", None, "steps that returned MEASUREMENT_REJECTED"),
                Member("unsigned long long", "failed", None, "steps that returned any other code but OK"),
                Member("REAL", "acc", self.acc, "x(k|k-1) then P(k|k-1)"),
                Member("REAL", "acc_next", self.acc, "scratch: x(k+1|k) then P(k+1|k)"),
                Member("REAL", "c", self.c, "theta, Qc, input noise, R"),
                Member("REAL", "d", self.d, "the sample: y, mask, u, u_start, u_end, dt"),
                Member("REAL", "record", self.record, "x(k|k), P(k|k), e, S, log-likelihood terms"),
                Member("REAL", "record_next", self.record, "scratch of record"),
                Member("REAL", "w", self.w, "generated code's work"),
                Member("REAL", "check", max(self.n, self.ny) ** 2, "Cholesky factors of init's checks and the gate's"),
                Member("REAL", "solve", self.ny, "the gate's whitened innovation"),
                Member("REAL", "gate", None, "the gate's threshold (0: off)"),
                Member("const REAL *", "arg", self.arg, "generated code's arguments"),
                Member("REAL *", "res", self.res, "generated code's results"),
                Member("int", "channel", self.ny, "the gate's measured channels")]

    def struct_bytes(self, real_bytes: int, pointer_bytes: int) -> int:
        """The ``sizeof`` of ``NAME_t`` (:func:`casest.export.c_common.struct_bytes`).

        Parameters
        ----------
        real_bytes, pointer_bytes : int

        Returns
        -------
        int
        """
        return struct_bytes(self.members(), pointer_bytes, real_bytes)

    def work_bytes(self, real_bytes: int, pointer_bytes: int) -> int:
        """Bytes of the generated code's work arrays inside ``NAME_t`` (w, iw, arg, res).

        Parameters
        ----------
        real_bytes, pointer_bytes : int

        Returns
        -------
        int
        """
        return work_bytes(self.members(), pointer_bytes, real_bytes)


def filter_header(name: str, s: FilterSizes, kind: str, model_name: str, real: str, stack: dict | None) -> str:
    """``NAME.h`` of an exported filter (module docstring).

    Parameters
    ----------
    name : str
        The C prefix.
    s : FilterSizes
    kind : {"ekf", "iekf", "ukf"}
    model_name : str
    real : {"double", "float"}
    stack : dict or None
        ``{"bytes", "function", "compiler"}``: the largest stack a call uses, measured
        (:func:`casest.export.c_memory.stack_use`), or None where no compiler was found.

    Returns
    -------
    str
    """
    up, rb = name.upper(), (4 if real == "float" else 8)
    memory = memory_macros_c(name, f"{name}_t", (s.struct_bytes(rb, 8), s.work_bytes(rb, 8)),
                             (s.struct_bytes(rb, 4), s.work_bytes(rb, 4)), stack)
    return f"""/**
 * @file {name}.h
 * @brief The {kind.upper()} of casest's model `{model_name}`, generated by casest (see README.md).
 *
 * Memory: one caller-owned {name}_t holds everything (no heap; libm and the C standard library
 * only). Declare it static or global rather than on a small task stack.
 *
 * Failure semantics: a step is computed into scratch and committed only when every check passes.
 * A NaN or infinite measurement, a non-finite update or a measurement beyond the gate drops
 * that sample's measurements and only predicts (as a sample without measurements would); a
 * non-finite input or dt, or a failed evaluation, keeps the state as it was. The next step goes
 * on from the last good state; {name}_t counts the rejected and failed steps.
 *
 * Matrices are column-major; units are the model's.
 */
#ifndef {up}_H
#define {up}_H

#define {up}_N_STATES {s.n}
#define {up}_N_OUTPUTS {s.ny}
#define {up}_N_INPUTS {s.nu}
#define {up}_N_STEP_INPUTS {s.nuk}
#define {up}_N_PARAMETERS {s.npar}

{memory}

typedef {real} {name}_real;  /**< the precision of every array and argument */

{status_enum_c(name, STATUS_CODES)}

/** All the filter's memory (sizeof is {up}_STRUCT_BYTES). Its counters rejected and failed may be
    read; the rest is the filter's. */
{struct_c(f"{name}_t", s.members(), f"{name}_real")}

{_declarations_c(name, s)}#endif
"""


def _declarations_c(name: str, s: FilterSizes) -> str:
    """The header's documented declarations of ``NAME_init``, ``NAME_step`` and the accessors."""
    up = name.upper()
    return f"""/**
 * @brief Start the filter: check every argument, then copy it into f.
 * @param f the filter's memory
 * @param x0 the start x(0|-1), {s.n} values
 * @param P0 its covariance, {s.n} x {s.n}, symmetric positive semidefinite (zero: a known start)
 * @param theta the model's parameters, {s.npar} values{" (may be NULL)" if s.npar == 0 else ""}
 * @param Qc the process noise's spectral density, {s.n} x {s.n}, symmetric positive semidefinite
 * @param input_noise the variances of white noise on the {s.nu} inputs (EKF), or NULL for none{"; unused by the UKF" if not s.input_noise else ""}
 * @param R the measurement noise covariance, {s.ny} x {s.ny}, symmetric positive definite
 * @param gate the innovation gate: a sample whose normalised innovation squared e' S^-1 e (over
 *        its measured channels) exceeds it is rejected; a chi-square quantile for the number of
 *        channels (e.g. 16.27: 0.1 % for 3), or 0 for no gate
 * @return {up}_OK, {up}_INVALID_ARGUMENT, {up}_R_NOT_POSITIVE_DEFINITE or
 *         {up}_COVARIANCE_NOT_POSITIVE_SEMIDEFINITE (then f is not started). After init,
 *         {name}_state is x0 and {name}_covariance P0.
 */
{name}_status_t {name}_init({name}_t *f, const {name}_real *x0, const {name}_real *P0, const {name}_real *theta,
    const {name}_real *Qc, const {name}_real *input_noise, const {name}_real *R, {name}_real gate);

/**
 * @brief One sample: the measurement update with y(k), then the time update to k+1.
 * @param f a started filter
 * @param y the {s.ny} measurements (entries of unmeasured channels are ignored)
 * @param measured {s.ny} flags (non-zero: measured), or NULL: the channels whose y is finite
 * @param u the {s.nu} inputs at the sample{" (may be NULL)" if s.nu == 0 else ""}
 * @param u_start the {s.nuk} inputs the time update reads at the interval's start
 * @param u_end the {s.nuk} at its end (a linear hold), or NULL: u_start
 * @param dt the interval to the next sample (the model's time unit)
 * @return {up}_OK, or the code of what failed (the enum above: what the state is after each).
 */
{name}_status_t {name}_step({name}_t *f, const {name}_real *y, const int *measured, const {name}_real *u,
    const {name}_real *u_start, const {name}_real *u_end, {name}_real dt);

/** @return x(k|k), {s.n} values (x0 after init; the last good one after a failed step) */
const {name}_real *{name}_state(const {name}_t *f);
/** @return P(k|k), {s.n} x {s.n} */
const {name}_real *{name}_covariance(const {name}_t *f);
/** @return the innovation y - h of the last committed step, {s.ny} values (0: not measured) */
const {name}_real *{name}_innovation(const {name}_t *f);
/** @return its covariance S, {s.ny} x {s.ny} */
const {name}_real *{name}_innovation_covariance(const {name}_t *f);
/** @return x(k+1|k), {s.n} values */
const {name}_real *{name}_predicted_state(const {name}_t *f);
/** @return P(k+1|k), {s.n} x {s.n} */
const {name}_real *{name}_predicted_covariance(const {name}_t *f);
/** @return the log-likelihood of the last committed step's measurements (0 before the first step; its
    logarithms are taken at this call, not at every step) */
{name}_real {name}_log_likelihood(const {name}_t *f);

"""


def filter_api(name: str, s: FilterSizes, real: str) -> str:
    """The wrapper's C: the checks, ``NAME_init``, ``NAME_step`` and the accessors.

    Parameters
    ----------
    name : str
    s : FilterSizes
    real : {"double", "float"}

    Returns
    -------
    str
    """
    return ("\n/* casest's wrapper of the generated step (its headers: WRAPPER_INCLUDES, at the file's top) */\n"
            + _checks_c(name, real) + _gate_c(name, s, real) + _init_c(name, s, real)
            + _evaluate_c(name, s, real) + _step_c(name, s, real) + _accessors_c(name, s, real))


def _checks_c(name: str, real: str) -> str:
    """``NAME_finite``, ``NAME_cholesky`` and ``NAME_semidefinite``, in the export's own precision."""
    return finite_c(name) + cholesky_c(name, real, semidefinite=True)


def _gate_c(name: str, s: FilterSizes, real: str) -> str:
    """``NAME_nis``: the normalised innovation squared of the step in scratch."""
    ny, n = s.ny, s.n
    zero, minus = literal("0.0", real), literal("-1.0", real)
    e_at, S_at = n + n * n, n + n * n + ny
    return f"""
/* The normalised innovation squared e' S^-1 e over the measured channels of the step in scratch,
   or -1 where their innovation covariance is not positive definite. */
static {name}_real {name}_nis({name}_t *f) {{
  int i;
  int j;
  int k;
  int m = 0;
  {name}_real sum = {zero};
  {name}_real value;
  bool ok;
  for (j = 0; j < {ny}; ++j) {{
    if (f->d[{ny} + j] > {zero}) {{
      f->channel[m] = j;
      m++;
    }}
  }}
  for (j = 0; j < m; ++j) {{
    for (i = 0; i < m; ++i) {{
      f->check[i + (j * m)] = f->record_next[{S_at} + f->channel[i] + ({ny} * f->channel[j])];
    }}
  }}
  ok = {name}_cholesky(f->check, f->check, m, {zero});
  for (i = 0; (i < m) && ok; ++i) {{
    value = f->record_next[{e_at} + f->channel[i]];
    for (k = 0; k < i; ++k) {{
      value -= f->check[i + (k * m)] * f->solve[k];
    }}
    f->solve[i] = value / f->check[i + (i * m)];
    sum += f->solve[i] * f->solve[i];
  }}
  return ok ? sum : {minus};
}}
"""


def _init_c(name: str, s: FilterSizes, real: str) -> str:
    """``NAME_init``: every argument checked, then copied into the struct."""
    n, ny, nu, up = s.n, s.ny, s.nu, name.upper()
    zero, one = literal("0.0", real), literal("1.0", real)
    size = f"sizeof({name}_real)"
    theta_null = " && (theta != NULL)" if s.npar > 0 else ""
    theta_finite = f"\n  ok = ok && {name}_finite(theta, {s.npar});" if s.npar > 0 else ""
    theta_copy = f"\n    (void)memcpy(f->c, theta, {s.npar}U * {size});" if s.npar > 0 else ""
    if s.input_noise and nu > 0:
        noise_finite = f"\n  ok = ok && ((input_noise == NULL) || {name}_finite(input_noise, {nu}));"
        noise_copy = (f"\n    if (input_noise != NULL) {{\n      (void)memcpy(&f->c[{s.npar + n * n}], input_noise, {nu}U * {size});"
                      "\n    }")
    else:
        noise_finite, noise_copy = "\n  (void)input_noise;  /* this filter takes no input noise */", ""
    r_at = s.npar + n * n + (nu if s.input_noise else 0)
    return f"""
{name}_status_t {name}_init({name}_t *f, const {name}_real *x0, const {name}_real *P0, const {name}_real *theta,
    const {name}_real *Qc, const {name}_real *input_noise, const {name}_real *R, {name}_real gate) {{
  {name}_status_t status = {up}_OK;
  int j;
  bool ok = (f != NULL) && (x0 != NULL) && (P0 != NULL) && (Qc != NULL) && (R != NULL){theta_null};
  ok = ok && {name}_finite(x0, {n}) && {name}_finite(P0, {n * n}) && {name}_finite(Qc, {n * n});
  ok = ok && {name}_finite(R, {ny * ny}) && (isfinite(gate) != 0) && (gate >= {zero});{theta_finite}{noise_finite}
  if (!ok) {{
    status = {up}_INVALID_ARGUMENT;
  }} else if (!{name}_cholesky(f->check, R, {ny}, {zero})) {{
    status = {up}_R_NOT_POSITIVE_DEFINITE;
  }} else if (!{name}_semidefinite(f->check, P0, {n}) || !{name}_semidefinite(f->check, Qc, {n})) {{
    status = {up}_COVARIANCE_NOT_POSITIVE_SEMIDEFINITE;
  }} else {{
    (void)memset(f, 0, sizeof(*f));
    (void)memcpy(f->acc, x0, {n}U * {size});
    (void)memcpy(&f->acc[{n}], P0, {n * n}U * {size});
    (void)memcpy(f->record, x0, {n}U * {size});  /* the state before the first step: x0 */
    (void)memcpy(&f->record[{n}], P0, {n * n}U * {size});
    for (j = 0; j < {ny}; ++j) {{
      f->record[{s.pivots_at} + j] = {one};  /* no step yet: a log-likelihood of 0 */
    }}{theta_copy}
    (void)memcpy(&f->c[{s.npar}], Qc, {n * n}U * {size});{noise_copy}
    (void)memcpy(&f->c[{r_at}], R, {ny * ny}U * {size});
    f->gate = gate;
  }}
  return status;
}}
"""


def _evaluate_c(name: str, s: FilterSizes, real: str) -> str:
    """``NAME_evaluate`` (the generated step into scratch) and ``NAME_drop`` (a sample's
    measurements dropped, values too: 0 times inf is NaN)."""
    zero = literal("0.0", real)
    return f"""
/* The generated step from the committed state into scratch: false where it failed. */
static bool {name}_evaluate({name}_t *f) {{
  f->arg[0] = f->acc;
  f->arg[1] = f->d;
  f->arg[2] = f->c;
  f->res[0] = f->acc_next;
  f->res[1] = f->record_next;
  return {name}_sample(f->arg, f->res, f->iw, f->w, 0) == 0;
}}

/* Whether the step in scratch is valid where it is read: the prediction, and x, P, e, S and the
   log-likelihood's terms of the record finite, and every pivot of S = L D L' positive (S positive
   definite on the measured channels; a prediction that is not finite is not committed). */
static bool {name}_result_valid(const {name}_t *f) {{
  bool positive = true;
  int j;
  for (j = 0; j < {s.ny}; ++j) {{
    if (!(f->record_next[{s.pivots_at} + j] > {zero})) {{
      positive = false;
    }}
  }}
  return positive && {name}_finite(f->record_next, {s.record_used}) && {name}_finite(f->acc_next, {s.acc});
}}

/* The sample's measurements dropped: its values and its mask zero. */
static void {name}_drop({name}_t *f) {{
  int j;
  for (j = 0; j < {2 * s.ny}; ++j) {{
    f->d[j] = {zero};
  }}
}}
"""


def _step_c(name: str, s: FilterSizes, real: str) -> str:
    """``NAME_step``: the checks, the step into scratch, the fallbacks, the commit."""
    ny, nu, nuk, up = s.ny, s.nu, s.nuk, name.upper()
    zero, one = literal("0.0", real), literal("1.0", real)
    size = f"sizeof({name}_real)"
    u_ok = f" && (u != NULL) && {name}_finite(u, {nu})" if nu > 0 else ""
    u_copy = f"\n    (void)memcpy(&f->d[{2 * ny}], u, {nu}U * {size});" if nu > 0 else "\n    (void)u;"
    return f"""
{name}_status_t {name}_step({name}_t *f, const {name}_real *y, const int *measured, const {name}_real *u,
    const {name}_real *u_start, const {name}_real *u_end, {name}_real dt) {{
  {name}_status_t status = {up}_OK;
  const {name}_real *end = (u_end != NULL) ? u_end : u_start;
  bool go = true;
  bool seen;
  int j;
  if ((f == NULL) || (y == NULL) || (u_start == NULL)) {{
    status = {up}_INVALID_ARGUMENT;
    go = false;
  }} else if (!({name}_finite(u_start, {nuk}) && {name}_finite(end, {nuk}) && (isfinite(dt) != 0){u_ok})) {{
    status = {up}_NON_FINITE_INPUT;
    go = false;
  }} else {{
    for (j = 0; j < {ny}; ++j) {{
      seen = (measured != NULL) ? (measured[j] != 0) : (isfinite(y[j]) != 0);
      if (seen && (isfinite(y[j]) == 0)) {{
        status = {up}_NON_FINITE_MEASUREMENT;
      }}
      f->d[j] = seen ? y[j] : {zero};
      f->d[{ny} + j] = seen ? {one} : {zero};
    }}{u_copy}
    (void)memcpy(&f->d[{2 * ny + nu}], u_start, {nuk}U * {size});
    (void)memcpy(&f->d[{2 * ny + nu + nuk}], end, {nuk}U * {size});
    f->d[{2 * ny + nu + 2 * nuk}] = dt;
    if (status != {up}_OK) {{
      {name}_drop(f);
    }}
    go = {name}_evaluate(f);
  }}
  if (go && (status == {up}_OK)) {{
    if (!{name}_result_valid(f)) {{
      status = {up}_UPDATE_FAILED;
    }} else if ((f->gate > {zero}) && !({name}_nis(f) <= f->gate)) {{
      status = {up}_MEASUREMENT_REJECTED;
    }} else {{
      /* every check passed */
    }}
    if (status != {up}_OK) {{
      {name}_drop(f);
      go = {name}_evaluate(f) && {name}_result_valid(f);
    }}
  }} else if (go) {{
    go = {name}_result_valid(f);  /* the sample's measurements were dropped before the evaluation */
  }} else {{
    /* nothing was evaluated */
  }}
  if (f == NULL) {{
    /* nothing to count */
  }} else if (!go && (status != {up}_INVALID_ARGUMENT) && (status != {up}_NON_FINITE_INPUT)) {{
    status = {up}_EVALUATION_FAILED;
    f->failed += 1U;
  }} else if (go) {{
    (void)memcpy(f->acc, f->acc_next, {s.acc}U * {size});
    (void)memcpy(f->record, f->record_next, {s.record_used}U * {size});
    if (status == {up}_MEASUREMENT_REJECTED) {{
      f->rejected += 1U;
    }} else if (status != {up}_OK) {{
      f->failed += 1U;
    }} else {{
      /* a good step */
    }}
  }} else {{
    f->failed += 1U;  /* an invalid or non-finite input */
  }}
  return status;
}}
"""


def _accessors_c(name: str, s: FilterSizes, real: str) -> str:
    """The accessors of the committed record and prediction; the log-likelihood from its terms
    (the logarithms of the pivots taken here, on request, not at every step)."""
    n, ny = s.n, s.ny
    log, half = ("logf", "0.5f") if real == "float" else ("log", "0.5")
    return f"""
const {name}_real *{name}_state(const {name}_t *f) {{
  return f->record;
}}

const {name}_real *{name}_covariance(const {name}_t *f) {{
  return &f->record[{n}];
}}

const {name}_real *{name}_innovation(const {name}_t *f) {{
  return &f->record[{n + n * n}];
}}

const {name}_real *{name}_innovation_covariance(const {name}_t *f) {{
  return &f->record[{n + n * n + ny}];
}}

const {name}_real *{name}_predicted_state(const {name}_t *f) {{
  return f->acc;
}}

const {name}_real *{name}_predicted_covariance(const {name}_t *f) {{
  return &f->acc[{n}];
}}

{name}_real {name}_log_likelihood(const {name}_t *f) {{
  {name}_real value = f->record[{s.pivots_at - 1}];
  int j;
  for (j = 0; j < {ny}; ++j) {{
    value -= {half} * {log}(f->record[{s.pivots_at} + j]);
  }}
  return value;
}}
"""
