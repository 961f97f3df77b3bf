"""A recursion over a record as one C function: a CasADi step ``(acc, d_k[, c]) -> (acc_next[, r_k])``
generated to C and called in a C loop over the samples, each sample's accumulator and record
written in place into the output arrays (no per-sample call from C++, no chunks).

The step's code is CasADi's own code generation; the loop around it is a few lines of C
written here. The library is compiled once per source through the compile cache
(:func:`~casest._casadi.c_library.load_library`) and called through ctypes.
"""

from __future__ import annotations

import ctypes

import casadi as ca
import numpy as np

from .c_library import load_library
from .numerics import compiler_available

__all__ = ["RecordLoop"]

#: -O3 for the loop; neither -ffast-math nor fused multiply-adds: the results equal CasADi's evaluation to
#: rounding (contracted products differ by 1e-9 in the unscented filter's sigma-point sums)
_FLAGS = ("-O3", "-march=native", "-ffp-contract=off", "-shared", "-fPIC", "-fno-math-errno", "-Wl,-z,defs")

_LOOP = """
CASADI_SYMBOL_EXPORT int casest_record_loop(const casadi_real* acc0, const casadi_real* D, const casadi_real* c,
                                            long n, casadi_real* accs, casadi_real* records) {
  casadi_int sz_arg, sz_res, sz_iw, sz_w, k;
  const casadi_real** arg; casadi_real** res; casadi_int* iw; casadi_real* w; const casadi_real* prior;
  int flag = 0;
  STEP_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  arg = (const casadi_real**) calloc(sz_arg > 3 ? sz_arg : 3, sizeof(casadi_real*));
  res = (casadi_real**) calloc(sz_res > 2 ? sz_res : 2, sizeof(casadi_real*));
  iw = (casadi_int*) calloc(sz_iw > 1 ? sz_iw : 1, sizeof(casadi_int));
  w = (casadi_real*) calloc(sz_w > 1 ? sz_w : 1, sizeof(casadi_real));
  if (!arg || !res || !iw || !w) { flag = -1; goto done; }
  prior = acc0;
  for (k = 0; k < n; ++k) {
    arg[0] = prior; arg[1] = D + k * N_D; arg[2] = c;
    res[0] = accs + k * N_ACC; res[1] = N_RECORD ? records + k * N_RECORD : 0;
    if (STEP(arg, res, iw, w, 0)) { flag = (int) k + 1; goto done; }
    prior = accs + k * N_ACC;
  }
done:
  free(arg); free(res); free(iw); free(w);
  return flag;
}
"""


def _dense_step(step: ca.Function) -> ca.Function:
    """``step`` with dense outputs (the loop writes every entry of each sample's rows)."""
    if all(step.sparsity_out(k).is_dense() for k in range(step.n_out())):
        return step
    inputs = step.sx_in() if step.is_a("SXFunction") else step.mx_in()
    outputs = step(*inputs)
    outputs = list(outputs) if isinstance(outputs, (list, tuple)) else [outputs]
    return ca.Function(step.name() + "_dense", inputs, [ca.densify(o) for o in outputs])


def _source(step: ca.Function) -> str:
    """The step's generated C followed by the loop, with the step's name and sizes substituted."""
    gen = ca.CodeGenerator(step.name() + ".c", {"prefix": "casest_loop_"})
    gen.add(step)
    sizes = {"STEP": step.name(), "N_D": str(step.nnz_in(1)), "N_ACC": str(step.nnz_out(0)),
             "N_RECORD": str(step.nnz_out(1) if step.n_out() > 1 else 0)}
    loop = _LOOP
    for name, value in sizes.items():
        loop = loop.replace(name, value)
    return "#include <stdlib.h>\n" + gen.dump() + loop


class RecordLoop:
    """A step repeated over the rows of a record in one compiled C loop.

    Built by :meth:`build` from a step ``(acc, d_k[, c]) -> (acc_next[, record_k])`` with dense
    column inputs; calling it returns the accumulator after every sample and every sample's
    record, as CasADi's ``mapaccum`` of the step would.
    """

    def __init__(self, function, step: ca.Function):
        self._function = function
        self.n_acc, self.n_d = step.nnz_out(0), step.nnz_in(1)
        self.n_c = step.nnz_in(2) if step.n_in() > 2 else 0
        self.n_record = step.nnz_out(1) if step.n_out() > 1 else 0

    @classmethod
    def build(cls, step: ca.Function) -> "RecordLoop | None":
        """The compiled loop of ``step``, or None (no C compiler, no C code for the step, a
        failed compile, inputs that are not dense columns): the caller keeps its own path.

        Parameters
        ----------
        step : casadi.Function
            ``(acc, d[, c]) -> (acc_next[, record])``; ``acc`` and ``acc_next`` of one size.

        Returns
        -------
        RecordLoop or None
        """
        if not compiler_available() or step.n_in() not in (2, 3) or step.n_out() not in (1, 2):
            return None
        if any(not step.sparsity_in(k).is_dense() for k in range(step.n_in())) or step.nnz_in(0) != step.nnz_out(0):
            return None
        step = _dense_step(step)
        try:
            source = _source(step)
        except RuntimeError:  # a step CasADi cannot generate C for
            return None
        library = load_library(source, _FLAGS, prefix="loop_")
        if library is None:
            return None
        function = library.casest_record_loop
        function.restype = ctypes.c_int
        function.argtypes = [ctypes.c_void_p] * 3 + [ctypes.c_long] + [ctypes.c_void_p] * 2
        return cls(function, step)

    def __call__(self, acc0: np.ndarray, D: np.ndarray, c: np.ndarray | None = None) -> tuple:
        """Run the step over the rows of ``D`` from ``acc0``.

        Parameters
        ----------
        acc0 : ndarray, shape (n_acc,)
        D : ndarray, shape (N, n_d)
            One row per sample.
        c : ndarray, shape (n_c,), optional
            The constants every step reads.

        Returns
        -------
        accs : ndarray, shape (N, n_acc)
            The accumulator after each sample.
        records : ndarray, shape (N, n_record), or None for a step without records
        """
        D = np.ascontiguousarray(D, dtype=float).reshape(-1, self.n_d)
        acc0 = np.ascontiguousarray(acc0, dtype=float).reshape(self.n_acc)
        c = np.ascontiguousarray(np.zeros(0) if c is None else c, dtype=float).reshape(self.n_c)
        N = D.shape[0]
        accs = np.empty((N, self.n_acc))
        records = np.empty((N, self.n_record)) if self.n_record else None
        flag = self._function(acc0.ctypes.data, D.ctypes.data, c.ctypes.data if self.n_c else None, N,
                              accs.ctypes.data, records.ctypes.data if records is not None else None)
        if flag < 0:
            raise MemoryError("the record loop could not allocate the step's work arrays")
        if flag > 0:
            raise RuntimeError(f"the step failed at sample {flag - 1}")
        return accs, records
