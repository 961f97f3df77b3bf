"""The C API of the exported recursive estimators of a static model (recursive least squares,
recursive maximum likelihood): their status codes, struct and step.

A step reads one sample ``(x, z, measured)``, evaluates the generated update into scratch and
commits it only when it is finite: a non-finite signal (``NON_FINITE_INPUT``), a channel marked
measured whose value is not finite (``NON_FINITE_MEASUREMENT``), an update that is not finite
(``UPDATE_FAILED``) or a failed evaluation (``EVALUATION_FAILED``) leave the estimate as it was,
exactly as if the sample had not been given, and the next sample goes on from it.
"""

from __future__ import annotations

from .c_common import Member, memory_macros_c, status_enum_c, struct_bytes, struct_c, work_bytes

__all__ = ["STATIC_STATUS_CODES", "static_members", "static_step_c", "static_header", "STATIC_PUBLIC_CALLS"]

#: the status codes of a static model's recursive estimator: (enumerator suffix, value, meaning)
STATIC_STATUS_CODES = (
    ("OK", 0, "the step (or init) succeeded"),
    ("EVALUATION_FAILED", 1, "the generated code failed: the estimate was kept"),
    ("UPDATE_FAILED", 2, "the update is not finite (a singular information, an overflow): the estimate was kept"),
    ("NON_FINITE_INPUT", 3, "a signal x is not finite: nothing was evaluated, the estimate was kept"),
    ("INVALID_ARGUMENT", 4, "init: an argument is NULL, not finite or out of its range (not started)"),
    ("NOISE_NOT_POSITIVE", 5, "init: a noise variance or weight is not positive (not started)"),
    ("COVARIANCE_NOT_POSITIVE_DEFINITE", 6, "init: the start's covariance or information is not symmetric positive "
                                            "definite (not started)"),
    ("NON_FINITE_MEASUREMENT", 8, "a channel marked measured holds a NaN or an infinity: the sample was skipped, "
                                  "the estimate kept"),
)
#: the public calls every static estimator has (``NAME_`` + each), beside its accessors
STATIC_PUBLIC_CALLS = ("init", "step")


def static_members(n_acc: int, n_c: int, n_d: int, n_check: int, step) -> list:
    """The members of a static estimator's struct, 8-byte integers first.

    Parameters
    ----------
    n_acc, n_c, n_d : int
        The accumulator's, constants' and sample's sizes.
    n_check : int
        The square matrix init factors, its number of values.
    step : casadi.Function
        The sample Function (its work sizes).

    Returns
    -------
    list of Member
    """
    return [Member("long long", "iw", step.sz_iw(), "generated code's integer work"),
            Member("unsigned long long", "failed", None, "steps that returned any code but OK"),
            Member("REAL", "acc", n_acc, "the estimate"),
            Member("REAL", "acc_next", n_acc, "scratch of acc"),
            Member("REAL", "c", n_c, "the constants"),
            Member("REAL", "d", n_d, "the sample: x, z, mask"),
            Member("REAL", "w", step.sz_w(), "generated code's work"),
            Member("REAL", "check", n_check, "init's Cholesky factor"),
            Member("const REAL *", "arg", step.sz_arg(), "generated code's arguments"),
            Member("REAL *", "res", step.sz_res(), "generated code's results")]


def static_step_c(name: str, nx: int, ny: int, n_acc: int) -> str:
    """The C of ``NAME_step(f, x, z, measured)`` for a recursive estimator of a static model whose
    sample Function is ``(acc, d = [x; z; mask], c) -> acc_next`` (module docstring).

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
    up, size = name.upper(), f"sizeof({name}_real)"
    x_check = (f"\n  }} else if (!((x != NULL) && {name}_finite(x, {nx}))) {{\n    status = {up}_NON_FINITE_INPUT;"
               if nx > 0 else "")
    x_copy = f"\n    (void)memcpy(f->d, x, {nx}U * {size});" if nx > 0 else "\n    (void)x;"
    return f"""
{name}_status_t {name}_step({name}_t *f, const {name}_real *x, const {name}_real *z, const int *measured) {{
  {name}_status_t status = {up}_OK;
  bool seen;
  int j;
  if ((f == NULL) || (z == NULL)) {{
    status = {up}_INVALID_ARGUMENT;{x_check}
  }} else {{{x_copy}
    for (j = 0; j < {ny}; ++j) {{
      seen = (measured != NULL) ? (measured[j] != 0) : (isfinite(z[j]) != 0);
      if (seen && (isfinite(z[j]) == 0)) {{
        status = {up}_NON_FINITE_MEASUREMENT;
      }}
      f->d[{nx} + j] = seen ? z[j] : 0.0;
      f->d[{nx + ny} + j] = seen ? 1.0 : 0.0;
    }}
  }}
  if (status == {up}_OK) {{
    f->arg[0] = f->acc;
    f->arg[1] = f->d;
    f->arg[2] = f->c;
    f->res[0] = f->acc_next;
    if ({name}_sample(f->arg, f->res, f->iw, f->w, 0) != 0) {{
      status = {up}_EVALUATION_FAILED;
    }} else if (!{name}_finite(f->acc_next, {n_acc})) {{
      status = {up}_UPDATE_FAILED;
    }} else {{
      (void)memcpy(f->acc, f->acc_next, {n_acc}U * {size});
    }}
  }}
  if ((f != NULL) && (status != {up}_OK)) {{
    f->failed += 1U;
  }}
  return status;
}}
"""


def static_header(name: str, title: str, sizes: dict, members: list, init_c: str, accessors_c: str,
                  stack: dict | None) -> str:
    """``NAME.h`` of a static model's recursive estimator: sizes, memory, status codes, struct and
    calls, documented (Doxygen form).

    Parameters
    ----------
    name : str
        The C prefix.
    title : str
        What the export is, for the file's brief (e.g. "Recursive least squares of ...").
    sizes : dict
        ``{suffix: value}``: the ``NAME_N_...`` macros.
    members : list of Member
        The struct (:func:`static_members`).
    init_c : str
        The documented declaration of ``NAME_init``.
    accessors_c : str
        The documented declarations of the accessors.
    stack : dict or None
        :func:`casest.export.c_memory.stack_use`'s result.

    Returns
    -------
    str
    """
    up = name.upper()
    macros = "\n".join(f"#define {up}_N_{key} {value}" for key, value in sizes.items())
    memory = memory_macros_c(name, f"{name}_t", (struct_bytes(members, 8, 8), work_bytes(members, 8, 8)),
                             (struct_bytes(members, 4, 8), work_bytes(members, 4, 8)), stack)
    return f"""/**
 * @file {name}.h
 * @brief {title}, generated by casest (see README.md).
 *
 * Memory: one caller-owned {name}_t holds everything (no heap; libm and the C standard library
 * only); declare it static or global. A step is committed only when its update is finite: a
 * non-finite signal or measurement, a non-finite update or a failed evaluation leaves the
 * estimate as it was (as if the sample had not been given), and {name}_t counts such steps.
 * Matrices are column-major.
 */
#ifndef {up}_H
#define {up}_H

{macros}

{memory}

typedef double {name}_real;  /**< every number is a double */

{status_enum_c(name, STATIC_STATUS_CODES)}

/** All the estimator's memory (sizeof is {up}_STRUCT_BYTES). Its counter failed may be read; the
    rest is the estimator's. */
{struct_c(f"{name}_t", members, f"{name}_real")}

{init_c}

/**
 * @brief One sample: the update with (x, z), committed only when finite.
 * @param f a started estimator
 * @param x the {sizes["SIGNALS"]} signals{" (may be NULL)" if not sizes["SIGNALS"] else ""}
 * @param z the {sizes["OUTPUTS"]} measurements (entries of unmeasured channels are ignored)
 * @param measured {sizes["OUTPUTS"]} flags (non-zero: measured), or NULL: the channels whose z is finite
 * @return {up}_OK, or the code of what failed (the estimate is then kept).
 */
{name}_status_t {name}_step({name}_t *f, const {name}_real *x, const {name}_real *z, const int *measured);

{accessors_c}

#endif
"""
