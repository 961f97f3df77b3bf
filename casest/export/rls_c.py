"""Recursive least squares of a static model's linear parameters as dependency-free C.

:func:`export_rls_c` writes, for a :class:`casest.Model` split into xi1 (entering linearly) and
xi2 (:func:`casest.separate`), the recursive least squares of xi1 at a fixed xi2 (reference
summary Eq. 4.12 with the n x n inverse of Eq. 4.14, as :class:`casest.recursive.RecursiveLeastSquares`
with ``inversion="measurements"``): the measurement of a sample is ``z - b(x, xi2) = A(x, xi2)
xi1 + e`` with ``W = diag(w)``. The C API, in one caller-owned struct (no heap, libm only):

- ``NAME_init(f, xi1, P, xi2, w)``: the start (an estimate and its ``R_info^-1``, e.g. from a
  batch estimate or the first samples' least squares), the fixed xi2 and the weights;
- ``NAME_step(f, x, z, measured)``: one sample (``measured`` NULL: the channels whose z is finite);
- ``NAME_estimate``, ``NAME_covariance`` (xi1 and ``R_info^-1``, column-major).
"""

from __future__ import annotations

import os

import casadi as ca

from ..errors import OptionError
from ..models import Model
from .c_common import cholesky_c, finite_c
from .c_files import c_prefix, write_c_files
from .c_kernel import generated_c
from .c_memory import stack_use
from .filter_c_api import WRAPPER_INCLUDES
from .static_c_api import STATIC_PUBLIC_CALLS, static_header, static_members, static_step_c

__all__ = ["export_rls_c"]


def export_rls_c(model: Model, out: str | os.PathLike, name: str | None = None, partition=None,
                 force: bool = False) -> dict:
    """Write the C source, header and README of the recursive least squares of xi1 (module docstring).

    Parameters
    ----------
    model : Model
        A static model with parameters entering linearly.
    out : str or os.PathLike
        The folder (created if missing; the files written atomically, README.md keeping the
        sections of other exports: :mod:`casest.export.c_files`).
    name : str, optional
        The C prefix of every symbol (default ``casest_<model>_rls``).
    partition : Partition, optional
        The split of the parameters (default :func:`casest.separate` of the model).
    force : bool
        Replace files of the export's names that casest did not write.

    Returns
    -------
    ExportedFiles
        ``{"source", "header", "readme"}``: the paths written; its ``replaced``: the files
        casest did not write that ``force`` replaced.

    Raises
    ------
    OptionError
        Not a static Model, no linear parameter, a name that is not a usable C prefix, or a file in the way.
    """
    from ..problem.separate import separate

    if not isinstance(model, Model):
        raise OptionError(f"export_rls_c takes a static casest.Model, got {type(model).__name__}")
    partition = partition or separate(model)
    if partition.n_linear == 0:
        raise OptionError(f"{model.name} has no parameter entering linearly: there is nothing for recursive least "
                          "squares to estimate")
    name = c_prefix(name, f"casest_{model.name}_rls")
    step = rls_sample_function(model, partition)
    q, n2, nx, ny = partition.n_linear, partition.n_nonlinear, model.n_signals, model.n_outputs
    members = static_members(q + q * q, n2 + ny, nx + 2 * ny, q * q, step)
    source = generated_c(step, name, "double", WRAPPER_INCLUDES) + _api(name, q, n2, nx, ny)
    calls = tuple(f"{name}_{call}" for call in (*STATIC_PUBLIC_CALLS, "estimate", "covariance"))
    stack = stack_use(source, _header(name, model, q, n2, members, None), name, calls)
    return write_c_files(out, name, _header(name, model, q, n2, members, stack), source,
                         _readme(name, model, partition, stack), force)


def rls_sample_function(model: Model, partition) -> ca.Function:
    """One sample of the recursive least squares (Eq. 4.12, 4.14) as a CasADi Function.

    Parameters
    ----------
    model : Model
    partition : Partition

    Returns
    -------
    casadi.Function
        ``(acc = [xi1; vec R_info^-1], d = [x; z; mask], c = [xi2; w]) -> acc_next``.
    """
    q, n2, nx, ny = partition.n_linear, partition.n_nonlinear, model.n_signals, model.n_outputs
    acc, d, c = ca.SX.sym("acc", q + q * q), ca.SX.sym("d", nx + 2 * ny), ca.SX.sym("c", n2 + ny)
    p, Rinv = acc[:q], ca.reshape(acc[q:], q, q)
    x, z, m = d[:nx], d[nx:nx + ny], d[nx + ny:]
    xi2, w = c[:n2], c[n2:]
    H = ca.reshape(partition.A(x, xi2), ny, q)
    y = z - ca.vec(partition.b(x, xi2))
    Hm, ym = ca.mtimes(ca.diag(m), H), m * y
    S = ca.mtimes([Hm, Rinv, Hm.T]) + ca.diag(w)
    Rinv_next = Rinv - ca.mtimes([Rinv, Hm.T, ca.solve(S, ca.mtimes(Hm, Rinv))])  # Eq. 4.14
    p_next = p + ca.mtimes([Rinv_next, Hm.T, ca.diag(1.0 / w), ym - ca.mtimes(Hm, p)])  # Eq. 4.12
    return ca.Function("rls_sample", [acc, d, c], [ca.vertcat(p_next, ca.vec(0.5 * (Rinv_next + Rinv_next.T)))],
                       ["acc", "d", "c"], ["acc_next"])


def _header(name: str, model: Model, q: int, n2: int, members: list, stack: dict | None) -> str:
    nx, ny = model.n_signals, model.n_outputs
    init = f"""/**
 * @brief Start the estimator: check every argument, then copy it into f.
 * @param f the estimator's memory
 * @param xi1 the start of the {q} linear parameters (a batch estimate, or the least squares of the first samples)
 * @param P its covariance R_info^-1, {q} x {q}, symmetric positive definite
 * @param xi2 the {n2} nonlinear parameters, fixed{" (may be NULL)" if n2 == 0 else ""}
 * @param w the {ny} measurement noise variances (the weights' inverses: W = diag(1/w)), positive
 * @return {name.upper()}_OK, {name.upper()}_INVALID_ARGUMENT, {name.upper()}_NOISE_NOT_POSITIVE or
 *         {name.upper()}_COVARIANCE_NOT_POSITIVE_DEFINITE (then f is not started).
 */
{name}_status_t {name}_init({name}_t *f, const {name}_real *xi1, const {name}_real *P, const {name}_real *xi2,
    const {name}_real *w);"""
    accessors = f"""/** @return xi1, {q} values (the start after init; the last good one after a failed step) */
const {name}_real *{name}_estimate(const {name}_t *f);
/** @return its covariance R_info^-1, {q} x {q} */
const {name}_real *{name}_covariance(const {name}_t *f);"""
    return static_header(name, f"Recursive least squares of the linear parameters of casest's model `{model.name}`",
                         {"LINEAR": q, "NONLINEAR": n2, "SIGNALS": nx, "OUTPUTS": ny}, members, init, accessors,
                         stack)


def _api(name: str, q: int, n2: int, nx: int, ny: int) -> str:
    up, size = name.upper(), f"sizeof({name}_real)"
    xi2_check = f" && (xi2 != NULL) && {name}_finite(xi2, {n2})" if n2 > 0 else ""
    xi2_copy = f"\n    (void)memcpy(f->c, xi2, {n2}U * {size});" if n2 > 0 else "\n    (void)xi2;"
    return """
/* casest's wrapper of the generated step (its headers at the file's top) */
""" + finite_c(name) + cholesky_c(name, "double") + f"""
{name}_status_t {name}_init({name}_t *f, const {name}_real *xi1, const {name}_real *P, const {name}_real *xi2,
    const {name}_real *w) {{
  {name}_status_t status = {up}_OK;
  bool positive = true;
  int j;
  bool ok = (f != NULL) && (xi1 != NULL) && (P != NULL) && (w != NULL);
  ok = ok && {name}_finite(xi1, {q}) && {name}_finite(P, {q * q}) && {name}_finite(w, {ny}){xi2_check};
  if (ok) {{
    for (j = 0; j < {ny}; ++j) {{
      if (!(w[j] > 0.0)) {{
        positive = false;
      }}
    }}
  }}
  if (!ok) {{
    status = {up}_INVALID_ARGUMENT;
  }} else if (!positive) {{
    status = {up}_NOISE_NOT_POSITIVE;
  }} else if (!{name}_cholesky(f->check, P, {q}, 0.0)) {{
    status = {up}_COVARIANCE_NOT_POSITIVE_DEFINITE;
  }} else {{
    (void)memset(f, 0, sizeof(*f));
    (void)memcpy(f->acc, xi1, {q}U * {size});
    (void)memcpy(&f->acc[{q}], P, {q * q}U * {size});{xi2_copy}
    (void)memcpy(&f->c[{n2}], w, {ny}U * {size});
  }}
  return status;
}}
""" + static_step_c(name, nx, ny, q + q * q) + f"""
const {name}_real *{name}_estimate(const {name}_t *f) {{
  return f->acc;
}}

const {name}_real *{name}_covariance(const {name}_t *f) {{
  return &f->acc[{q}];
}}
"""


def _readme(name: str, model: Model, partition, stack: dict | None) -> str:
    stack_text = f"{stack['bytes']} bytes of stack at most ({stack['compiler']})" if stack else "stack not measured"
    return f"""# {name}

Recursive least squares of the linear parameters of casest's model `{model.name}` at a fixed
value of the others (reference summary Eq. 4.12, 4.14), generated by `casest.export.rls_c`
as C99 needing only the C standard library and libm; all memory is one caller-owned `{name}_t`
(`{name.upper()}_STRUCT_BYTES`; {stack_text}). **`{name}.h` documents every call**: its
arguments, sizes and return codes.

- linear parameters xi1, estimated ({partition.n_linear}): {", ".join(partition.linear)}
- nonlinear parameters xi2, fixed ({partition.n_nonlinear}): {", ".join(partition.nonlinear) or "none"}
- signals x ({model.n_signals}): {", ".join(model.signal_names)}
- outputs z ({model.n_outputs}): {", ".join(model.output_names)}

Build: `cc -std=c99 -O2 -c {name}.c` (link with `-lm`). Start from an estimate and its `R_info^-1` (a
batch estimate, or the least squares of the first samples), then one `{name}_step(&f, x, z, NULL)` per
sample; `{name}_estimate(&f)` is xi1. A sample whose signals, measurements or update are not finite is
skipped (the step says which); the estimate stays the last good one. The code is double precision only.
"""
