"""Recursive maximum likelihood of a static model as dependency-free C.

:func:`export_rml_c` writes, for a :class:`casest.Model`, the recursive ML of theta and a diagonal
R of :class:`casest.recursive.RecursiveML` one sample at a time (reference summary Eq. 5.8-5.13: one
Newton step on the new sample's gradient with the accumulated Gauss-Newton information, the
information discounted by the forgetting factor lambda(k) -> 1 at the rate r, theta held in its
box). The C API, in one caller-owned struct (no heap, libm only):

- ``NAME_init(f, theta, R, information, forgetting, forgetting_rate)``: the start (theta, the
  noise variances R, the information of [theta; ln R], column-major, lambda(0) and r);
- ``NAME_step(f, x, z, measured)``: one sample (``measured`` NULL: the channels whose z is finite);
- ``NAME_estimate`` (theta), ``NAME_log_noise`` (ln R), ``NAME_information``.
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

__all__ = ["export_rml_c", "rml_sample_function"]


def export_rml_c(model: Model, out: str | os.PathLike, name: str | None = None, force: bool = False) -> dict:
    """Write the C source, header and README of a static model's recursive ML (module docstring).

    Parameters
    ----------
    model : Model
    out : str or os.PathLike
        The folder (created if missing; the files written atomically, README.md keeping the
        sections of other exports: :mod:`casest.export.c_files`).
    name : str, optional
        The C prefix of every symbol (default ``casest_<model>_rml``).
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
        Not a static Model, a name that is not a usable C prefix, or a file in the way.
    """
    if not isinstance(model, Model):
        raise OptionError(f"export_rml_c takes a static casest.Model, got {type(model).__name__}")
    name = c_prefix(name, f"casest_{model.name}_rml")
    step = rml_sample_function(model)
    n, ny, nx = model.n_parameters, model.n_outputs, model.n_signals
    m = n + ny
    members = static_members(m + m * m + 1, 1, nx + 2 * ny, m * m, step)
    source = generated_c(step, name, "double", WRAPPER_INCLUDES) + _api(name, n, ny, nx)
    calls = tuple(f"{name}_{call}" for call in (*STATIC_PUBLIC_CALLS, "estimate", "log_noise", "information"))
    stack = stack_use(source, _header(name, model, members, None), name, calls)
    return write_c_files(out, name, _header(name, model, members, stack), source, _readme(name, model, stack), force)


def rml_sample_function(model: Model) -> ca.Function:
    """One sample of :class:`casest.recursive.RecursiveML` on a static model as a CasADi Function.

    Parameters
    ----------
    model : Model

    Returns
    -------
    casadi.Function
        ``(acc = [theta; ln R; vec information; lambda], d = [x; z; mask], c = [r]) -> acc_next``.
    """
    n, ny, nx = model.n_parameters, model.n_outputs, model.n_signals
    m = n + ny
    acc, d, c = ca.SX.sym("acc", m + m * m + 1), ca.SX.sym("d", nx + 2 * ny), ca.SX.sym("c", 1)
    theta, rho, info, lam = acc[:n], acc[n:m], ca.reshape(acc[m:m + m * m], m, m), acc[m + m * m]
    x, z, mask = d[:nx], d[nx:nx + ny], d[nx + ny:]
    h = ca.vec(model.function(x, theta))
    e = mask * (z - h)                                   # prediction errors (Eq. 5.3)
    de = -ca.mtimes(ca.diag(mask), ca.jacobian(h, theta))  # d e / d theta, rows not measured zero
    R = ca.exp(rho)
    grad = ca.vertcat(ca.mtimes(de.T, e / R), 0.5 * mask * (1.0 - e ** 2 / R))  # Eq. 5.10, 5.12-5.13
    added = ca.diagcat(ca.mtimes([de.T, ca.diag(1.0 / R), de]), ca.diag(0.5 * mask))  # Eq. 5.11
    info_next = info * lam + added
    step = ca.solve(info_next, grad)
    theta_next = ca.fmin(ca.fmax(theta - step[:n], ca.DM(model.lower_bounds)), ca.DM(model.upper_bounds))
    lam_next = c[0] * lam + (1.0 - c[0])
    return ca.Function("rml_sample", [acc, d, c],
                       [ca.vertcat(theta_next, rho - step[n:], ca.vec(info_next), lam_next)],
                       ["acc", "d", "c"], ["acc_next"])


def _header(name: str, model: Model, members: list, stack: dict | None) -> str:
    n, ny, nx, up = model.n_parameters, model.n_outputs, model.n_signals, name.upper()
    m = n + ny
    init = f"""/**
 * @brief Start the estimator: check every argument, then copy it into f.
 * @param f the estimator's memory
 * @param theta the start of the {n} parameters
 * @param R the start of the {ny} noise variances, positive
 * @param information the information of [theta; ln R], {m} x {m}, symmetric positive definite
 * @param forgetting lambda(0), in (0, 1] (1: no forgetting)
 * @param forgetting_rate r, in (0, 1]: lambda(k+1) = r lambda(k) + 1 - r
 * @return {up}_OK, {up}_INVALID_ARGUMENT, {up}_NOISE_NOT_POSITIVE or
 *         {up}_COVARIANCE_NOT_POSITIVE_DEFINITE (then f is not started).
 */
{name}_status_t {name}_init({name}_t *f, const {name}_real *theta, const {name}_real *R,
    const {name}_real *information, {name}_real forgetting, {name}_real forgetting_rate);"""
    accessors = f"""/** @return theta, {n} values (the start after init; the last good one after a failed step) */
const {name}_real *{name}_estimate(const {name}_t *f);
/** @return ln R, {ny} values */
const {name}_real *{name}_log_noise(const {name}_t *f);
/** @return the information of [theta; ln R], {m} x {m} */
const {name}_real *{name}_information(const {name}_t *f);"""
    return static_header(name, f"Recursive maximum likelihood of casest's model `{model.name}`",
                         {"PARAMETERS": n, "OUTPUTS": ny, "SIGNALS": nx}, members, init, accessors, stack)


def _api(name: str, n: int, ny: int, nx: int) -> str:
    m, up, size = n + ny, name.upper(), f"sizeof({name}_real)"
    return """
/* casest's wrapper of the generated step (its headers at the file's top) */
""" + finite_c(name) + cholesky_c(name, "double") + f"""
{name}_status_t {name}_init({name}_t *f, const {name}_real *theta, const {name}_real *R,
    const {name}_real *information, {name}_real forgetting, {name}_real forgetting_rate) {{
  {name}_status_t status = {up}_OK;
  bool positive = true;
  int j;
  bool ok = (f != NULL) && (theta != NULL) && (R != NULL) && (information != NULL);
  ok = ok && {name}_finite(theta, {n}) && {name}_finite(R, {ny}) && {name}_finite(information, {m * m});
  ok = ok && (forgetting > 0.0) && (forgetting <= 1.0) && (forgetting_rate > 0.0) && (forgetting_rate <= 1.0);
  if (ok) {{
    for (j = 0; j < {ny}; ++j) {{
      if (!(R[j] > 0.0)) {{
        positive = false;
      }}
    }}
  }}
  if (!ok) {{
    status = {up}_INVALID_ARGUMENT;
  }} else if (!positive) {{
    status = {up}_NOISE_NOT_POSITIVE;
  }} else if (!{name}_cholesky(f->check, information, {m}, 0.0)) {{
    status = {up}_COVARIANCE_NOT_POSITIVE_DEFINITE;
  }} else {{
    (void)memset(f, 0, sizeof(*f));
    (void)memcpy(f->acc, theta, {n}U * {size});
    for (j = 0; j < {ny}; ++j) {{
      f->acc[{n} + j] = log(R[j]);
    }}
    (void)memcpy(&f->acc[{m}], information, {m * m}U * {size});
    f->acc[{m + m * m}] = forgetting;
    f->c[0] = forgetting_rate;
  }}
  return status;
}}
""" + static_step_c(name, nx, ny, m + m * m + 1) + f"""
const {name}_real *{name}_estimate(const {name}_t *f) {{
  return f->acc;
}}

const {name}_real *{name}_log_noise(const {name}_t *f) {{
  return &f->acc[{n}];
}}

const {name}_real *{name}_information(const {name}_t *f) {{
  return &f->acc[{m}];
}}
"""


def _readme(name: str, model: Model, stack: dict | None) -> str:
    stack_text = f"{stack['bytes']} bytes of stack at most ({stack['compiler']})" if stack else "stack not measured"
    return f"""# {name}

Recursive maximum likelihood of theta and a diagonal R for casest's model `{model.name}`, one sample
at a time (reference summary Eq. 5.8-5.13, as `casest.recursive.RecursiveML`), generated by
`casest.export.rml_c` as C99 needing only the C standard library and libm; all memory is one
caller-owned `{name}_t` (`{name.upper()}_STRUCT_BYTES`; {stack_text}). **`{name}.h` documents every
call**: its arguments, sizes and return codes.

- parameters ({model.n_parameters}): {", ".join(model.parameter_names)} (held in their box)
- signals x ({model.n_signals}): {", ".join(model.signal_names)}
- outputs z ({model.n_outputs}): {", ".join(model.output_names)}

Build: `cc -std=c99 -O2 -c {name}.c` (link with `-lm`). `{name}_init(&f, theta0, R0, information0,
lambda0, r)` (`information0` of [theta; ln R], column-major; lambda0 = 1 for no forgetting), then
one `{name}_step(&f, x, z, NULL)` per sample. A sample whose signals, measurements or update are not
finite is skipped (the step says which); the estimate stays the last good one. The code is double
precision only.
"""
