"""The batch two-stage estimator as dependency-free C, for re-calibration on board from a stored
window of fixed length.

:func:`export_two_stage_c` code-generates :func:`casest.interop.two_stage_graph_function` with
``solver="sqpmethod"`` (stage 1 over a fixed design, stage 2 by CasADi's SQP method with its
``qrqp`` QP solver: no IPOPT, no Python) and wraps it in one C call whose work memory is a
caller-owned struct of fixed size (no heap, libm only):

- ``NAME_estimate(work, signals, outputs, theta, R, cov, success)``: ``signals``
  (n_signals x N) and ``outputs`` (n_outputs x N), column-major (one sample after the other);
  returns ``NAME_OK``, or the code of what failed (a NULL argument, a non-finite sample, the
  generated code); ``success`` is 1.0 where stage 2 converged.

The work storage is the caller's (``NAME_WORK_BYTES``, hundreds of kB for windows of a few hundred
samples: a static buffer, never a task's stack); the header states it and the call's own stack.
"""

from __future__ import annotations

import os

import casadi as ca

from ..models import Model
from .c_common import Member, finite_c, memory_macros_c, status_enum_c, struct_bytes, struct_c
from .c_files import c_prefix, quiet_unused_parameters, write_c_files
from .c_kernel import KERNEL_MARK, explicit_truth_values
from .c_memory import stack_use
from .filter_c_api import WRAPPER_INCLUDES

__all__ = ["export_two_stage_c"]


def export_two_stage_c(model: Model, n_samples: int, out: str | os.PathLike, name: str | None = None,
                       sweep_settings=None, solver_settings=None, force: bool = False) -> dict:
    """Write the C source, header and README of the two-stage estimator over windows of
    ``n_samples`` samples (module docstring).

    Parameters
    ----------
    model : Model
        A static model with at least one nonlinear parameter and bounded xi2.
    n_samples : int
        N, the window's length (fixed in the generated code).
    out : str or os.PathLike
        The folder (created if missing; the files written atomically, README.md keeping the
        sections of other exports: :mod:`casest.export.c_files`).
    name : str, optional
        The C prefix of every symbol (default ``casest_<model>_two_stage``).
    sweep_settings, solver_settings : optional
        Stage 1's design and stage 2's tolerance and iterations
        (:func:`casest.interop.two_stage_graph_function`).
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
        As :func:`casest.interop.two_stage_graph_function`, a name that is not a usable C prefix, or a file in the way.
    """
    from ..interop.two_stage_graph import two_stage_graph_function

    name = c_prefix(name, f"casest_{getattr(model, 'name', 'model')}_two_stage")
    graph = two_stage_graph_function(model, n_samples, sweep_settings, solver_settings, solver="sqpmethod",
                                     name=f"{name}_graph")
    generator = ca.CodeGenerator(f"{name}_graph", {"with_header": False, "with_mem": False, "main": False,
                                                  "casadi_real": "double", "casadi_int": "long long"})
    generator.add(graph)
    N = int(n_samples)
    source = (f'#include "{name}.h"\n' + WRAPPER_INCLUDES + KERNEL_MARK + "\n"
              + explicit_truth_values(quiet_unused_parameters(generator.dump())) + _api(name, model, N))
    members = _members(graph)
    stack = stack_use(source, _header(name, model, N, members, None), name, (f"{name}_estimate",))
    return write_c_files(out, name, _header(name, model, N, members, stack), source,
                         _readme(name, model, N, members, stack), force)


def _members(graph: ca.Function) -> list:
    """The work struct's members, 8-byte integers first."""
    return [Member("long long", "iw", graph.sz_iw(), "generated code's integer work"),
            Member("REAL", "w", graph.sz_w(), "generated code's work"),
            Member("const REAL *", "arg", graph.sz_arg(), "generated code's arguments"),
            Member("REAL *", "res", graph.sz_res(), "generated code's results")]


#: the status codes of the batch estimator: (enumerator suffix, value, meaning)
BATCH_STATUS_CODES = (
    ("OK", 0, "the estimate was computed (read success for stage 2's convergence)"),
    ("EVALUATION_FAILED", 1, "the generated code failed"),
    ("NON_FINITE_INPUT", 3, "a signal or an output is not finite: nothing was evaluated"),
    ("INVALID_ARGUMENT", 4, "an argument is NULL"),
)


def _header(name: str, model: Model, N: int, members: list, stack: dict | None) -> str:
    up, n, ny, nx = name.upper(), model.n_parameters, model.n_outputs, model.n_signals
    memory = memory_macros_c(name, f"{name}_work_t", (struct_bytes(members, 8, 8), struct_bytes(members, 8, 8)),
                             (struct_bytes(members, 4, 8), struct_bytes(members, 4, 8)), stack)
    return f"""/**
 * @file {name}.h
 * @brief The two-stage estimator of casest's model `{model.name}` over windows of {N} samples,
 *        generated by casest (see README.md).
 *
 * Memory: the work storage is the caller's, one {name}_work_t of {up}_WORK_BYTES bytes; declare it
 * static or global (it is far larger than a task's stack). The call itself needs {up}_STACK_BYTES
 * of stack at most. No heap; libm and the C standard library only. Matrices are column-major.
 */
#ifndef {up}_H
#define {up}_H

#define {up}_N_SAMPLES {N}
#define {up}_N_SIGNALS {nx}
#define {up}_N_OUTPUTS {ny}
#define {up}_N_PARAMETERS {n}

{memory}

typedef double {name}_real;  /**< every number is a double */

{status_enum_c(name, BATCH_STATUS_CODES)}

/** The estimator's work storage (sizeof is {up}_WORK_BYTES); the estimator's own. */
{struct_c(f"{name}_work_t", members, f"{name}_real")}

/**
 * @brief Estimate the parameters from one window: stage 1 over its fixed design, stage 2 by SQP.
 * @param work the work storage (static or global)
 * @param signals the {nx} signals of the {N} samples, {nx} x {N}, one sample after the other
 * @param outputs the {ny} outputs of the {N} samples, {ny} x {N}, one sample after the other
 * @param theta out: the {n} parameters
 * @param R out: the {ny} noise variances
 * @param cov out: the parameters' covariance, {n} x {n}
 * @param success out: 1.0 where stage 2 converged, else 0.0
 * @return {up}_OK, or the code of what failed (the outputs are then not meaningful).
 */
{name}_status_t {name}_estimate({name}_work_t *work, const {name}_real *signals, const {name}_real *outputs,
    {name}_real *theta, {name}_real *R, {name}_real *cov, {name}_real *success);

#endif
"""


def _api(name: str, model: Model, N: int) -> str:
    up = name.upper()
    return """
/* casest's wrapper of the generated step (its headers at the file's top) */
""" + finite_c(name) + f"""
{name}_status_t {name}_estimate({name}_work_t *work, const {name}_real *signals, const {name}_real *outputs,
    {name}_real *theta, {name}_real *R, {name}_real *cov, {name}_real *success) {{
  {name}_status_t status = {up}_OK;
  if ((work == NULL) || (signals == NULL) || (outputs == NULL) || (theta == NULL) || (R == NULL) || (cov == NULL)
      || (success == NULL)) {{
    status = {up}_INVALID_ARGUMENT;
  }} else if (!({name}_finite(signals, {model.n_signals * N}) && {name}_finite(outputs, {model.n_outputs * N}))) {{
    status = {up}_NON_FINITE_INPUT;
  }} else {{
    work->arg[0] = signals;
    work->arg[1] = outputs;
    work->res[0] = theta;
    work->res[1] = R;
    work->res[2] = cov;
    work->res[3] = success;
    if ({name}_graph(work->arg, work->res, work->iw, work->w, 0) != 0) {{
      status = {up}_EVALUATION_FAILED;
    }}
  }}
  return status;
}}
"""


def _readme(name: str, model: Model, N: int, members: list, stack: dict | None) -> str:
    stack_text = f"{stack['bytes']} bytes ({stack['compiler']})" if stack else "not measured (no GCC at export)"
    return f"""# {name}

The two-stage estimator (stage 1 over a fixed design, stage 2 by CasADi's SQP method) of
casest's model `{model.name}` over windows of {N} samples, generated by
`casest.export.batch_c.export_two_stage_c` as C99 needing only the C standard library and
libm. **`{name}.h` documents the call**: its arguments, sizes and return codes.

- parameters ({model.n_parameters}): {", ".join(model.parameter_names)}
- signals ({model.n_signals}): {", ".join(model.signal_names)}; outputs ({model.n_outputs}):
  {", ".join(model.output_names)}

Memory: the work storage is the caller's: one `{name}_work_t` of `{name.upper()}_WORK_BYTES` =
{struct_bytes(members, 8, 8)} bytes (64-bit pointers; {struct_bytes(members, 4, 8)} with 32-bit ones), which
grows with the window. Declare it `static` or global, never on a task's stack. The call's own
stack: {stack_text}. No heap.

Build: `cc -std=c99 -O1 -c {name}.c` (link with `-lm`; the file is large, higher optimisation
compiles slowly).

```c
static {name}_work_t work;  /* static: {name.upper()}_WORK_BYTES bytes */
double theta[{model.n_parameters}], R[{model.n_outputs}], cov[{model.n_parameters * model.n_parameters}], success;
if ({name}_estimate(&work, signals, outputs, theta, R, cov, &success) == {name.upper()}_OK && success == 1.0) {{ ... }}
```

`signals` and `outputs` are column-major, one sample after the other. The code is double
precision only.
"""
