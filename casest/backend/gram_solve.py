"""The sweep's normal equations, candidate by candidate, in C.

Stage 1 turns each candidate's Gram sums (the upper triangle of ``[A, z - b]' [A, z - b]`` per
channel) into its xi1 and per-channel residual sums of squares. Done in NumPy across the stack
of candidates, that costs 0.3-3 us a candidate (a dozen array passes over tiny matrices), more
than the compiled sums themselves on a short record. :func:`gram_solver` compiles one C loop
(once per machine: the compile cache keeps it) that does, per candidate, what
:meth:`casest.two_stage.sweep.evaluators.GramEvaluator.solve` does in NumPy: column scaling,
the Cholesky screen of :func:`casest.backend.least_squares.condition_below`, the solve and the
residual sums. Each candidate gets a status; those the screen cannot decide, and those whose
normal equations lose accuracy, go back to the NumPy path as before.
"""

from __future__ import annotations

import ctypes

import numpy as np

from .least_squares import SCREEN_MARGIN, SCREENED_LIMIT

__all__ = ["GramSolver", "gram_solver", "ACCURATE", "RESOLVE", "NOT_A_FIT", "UNDECIDED", "MAX_LINEAR"]

#: statuses of a candidate: solved; finite with full columns but to be solved again from A (the
#: normal equations lose accuracy: RSS below 1e-8 y'y, or too ill-conditioned); not a fit (a sum
#: not finite, or a column of A zero at every sample); conditioning not decided by the screen
ACCURATE, RESOLVE, NOT_A_FIT, UNDECIDED = 0, 1, 2, 3
#: the most linear parameters the C loop takes (its work arrays are on the stack)
MAX_LINEAR = 31

_SOURCE = r"""
#include <math.h>
#define MAXN 32

/* flat: M x ny x T upper triangles (row by row) of the (n1 + 1)-square Gram matrices */
int casest_gram_solve(const double* flat, long M, long ny, long n1, double limit, double margin,
                      double* x, double* rss, signed char* status) {
  long n = n1 + 1, T = n * (n + 1) / 2, m, i, j, k, c, t;
  long idx[MAXN * MAXN];
  double P[MAXN * MAXN], L[MAXN * MAXN], Li[MAXN * MAXN], q[MAXN], d[MAXN], z[MAXN];
  if (n1 < 1 || n > MAXN) return -1;
  t = 0;
  for (i = 0; i < n; ++i) for (j = i; j < n; ++j) { idx[i * n + j] = t; idx[j * n + i] = t; ++t; }
  for (m = 0; m < M; ++m) {
    const double* g = flat + m * ny * T;
    double *xm = x + m * n1, *rm = rss + m * ny, trace = 0.0, fro = 0.0, bound;
    int fit = 1, accurate = 1;
    for (i = 0; i < n1; ++i) xm[i] = 0.0;
    for (c = 0; c < ny; ++c) rm[c] = NAN;
    for (t = 0; t < ny * T; ++t) if (!isfinite(g[t])) { fit = 0; break; }
    if (!fit) { status[m] = 2; continue; }
    for (i = 0; i < n1; ++i) {
      q[i] = 0.0;
      for (c = 0; c < ny; ++c) q[i] += g[c * T + idx[i * n + n1]];
      for (j = 0; j < n1; ++j) {
        P[i * n1 + j] = 0.0;
        for (c = 0; c < ny; ++c) P[i * n1 + j] += g[c * T + idx[i * n + j]];
      }
    }
    for (i = 0; i < n1; ++i) { d[i] = sqrt(P[i * n1 + i] > 0.0 ? P[i * n1 + i] : 0.0); if (d[i] == 0.0) fit = 0; }
    if (!fit) { status[m] = 2; continue; }
    for (i = 0; i < n1; ++i) for (j = 0; j < n1; ++j) P[i * n1 + j] = P[i * n1 + j] / (d[i] * d[j]);
    /* Cholesky P = L L' and ||L^-1||_F^2: trace P ||L^-1||_F^2 bounds the condition number */
    for (j = 0; j < n1 && fit; ++j) {
      double pivot = P[j * n1 + j];
      for (k = 0; k < j; ++k) pivot -= L[j * n1 + k] * L[j * n1 + k];
      if (!(pivot > 0.0)) { fit = 0; break; }
      L[j * n1 + j] = sqrt(pivot);
      for (i = j + 1; i < n1; ++i) {
        double s = P[i * n1 + j];
        for (k = 0; k < j; ++k) s -= L[i * n1 + k] * L[j * n1 + k];
        L[i * n1 + j] = s / L[j * n1 + j];
      }
    }
    if (!fit) { status[m] = 3; continue; }
    for (i = 0; i < n1; ++i) {
      trace += P[i * n1 + i];
      Li[i * n1 + i] = 1.0 / L[i * n1 + i];
      for (j = 0; j < i; ++j) {
        double s = 0.0;
        for (k = j; k < i; ++k) s += L[i * n1 + k] * Li[k * n1 + j];
        Li[i * n1 + j] = -s / L[i * n1 + i];
      }
      for (j = 0; j <= i; ++j) fro += Li[i * n1 + j] * Li[i * n1 + j];
    }
    bound = trace * fro;
    if (!(isfinite(bound) && bound * margin < limit)) { status[m] = 3; continue; }
    /* L L' z = q / d, then x = z / d */
    for (i = 0; i < n1; ++i) {
      double s = q[i] / d[i];
      for (k = 0; k < i; ++k) s -= L[i * n1 + k] * z[k];
      z[i] = s / L[i * n1 + i];
    }
    for (i = n1 - 1; i >= 0; --i) {
      double s = z[i];
      for (k = i + 1; k < n1; ++k) s -= L[k * n1 + i] * z[k];
      z[i] = s / L[i * n1 + i];
    }
    for (i = 0; i < n1; ++i) xm[i] = z[i] / d[i];
    /* per channel: y'y - 2 x'A'y + x'A'A x */
    for (c = 0; c < ny; ++c) {
      const double* gc = g + c * T;
      double yty = gc[idx[n1 * n + n1]], r = yty;
      for (i = 0; i < n1; ++i) {
        double row = 0.0;
        for (j = 0; j < n1; ++j) row += gc[idx[i * n + j]] * xm[j];
        r += xm[i] * (row - 2.0 * gc[idx[i * n + n1]]);
      }
      rm[c] = r;
      if (!(r > 1e-8 * yty)) accurate = 0;
    }
    status[m] = accurate ? 0 : 1;
  }
  return 0;
}
"""

_FLAGS = ("-O2", "-ffp-contract=off", "-fno-math-errno", "-shared", "-fPIC")


class GramSolver:
    """The compiled loop of :data:`_SOURCE` (built by :func:`gram_solver`)."""

    def __init__(self, function):
        self._function = function

    def __call__(self, flat: np.ndarray, n_outputs: int, n_linear: int, limit: float) -> tuple:
        """Each candidate's xi1, per-channel RSS and status.

        Parameters
        ----------
        flat : ndarray, shape (M, n_outputs * T)
            The upper triangles (``numpy.triu_indices`` order) of each candidate's Gram matrices,
            channel after channel; T = (n_linear + 1)(n_linear + 2) / 2.
        n_outputs, n_linear : int
        limit : float
            The largest accepted condition number of the column-scaled normal matrix.

        Returns
        -------
        x : ndarray, shape (M, n_linear)
            Zero where the status is not ``ACCURATE`` or ``RESOLVE``.
        rss : ndarray, shape (M, n_outputs)
            Residual sums of squares (NaN where not solved).
        status : ndarray of int8, shape (M,)
            ``ACCURATE``, ``RESOLVE``, ``NOT_A_FIT`` or ``UNDECIDED``.
        """
        flat = np.ascontiguousarray(flat, dtype=float)
        M = flat.shape[0]
        x, rss, status = np.empty((M, n_linear)), np.empty((M, n_outputs)), np.empty(M, dtype=np.int8)
        flag = self._function(flat.ctypes.data, M, n_outputs, n_linear, float(limit), SCREEN_MARGIN,
                              x.ctypes.data, rss.ctypes.data, status.ctypes.data)
        if flag:
            raise ValueError(f"the compiled normal equations take 1 to {MAX_LINEAR} linear parameters, got {n_linear}")
        return x, rss, status


def gram_solver(n_linear: int, limit: float, cached_only: bool) -> GramSolver | None:
    """The compiled per-candidate normal equations, or None (the caller keeps its NumPy path).

    Parameters
    ----------
    n_linear : int
        The candidates' linear parameters (1 to :data:`MAX_LINEAR`).
    limit : float
        The sweep's condition limit: above ``SCREENED_LIMIT`` every candidate would go to the
        eigenvalue test, so no compiled path.
    cached_only : bool
        Only a library this process or the compile cache already holds (compile nothing).

    Returns
    -------
    GramSolver or None
        None without a C compiler, outside those sizes, or ``cached_only`` with nothing compiled.
    """
    from .._casadi.c_library import load_library
    from .._casadi.numerics import compiler_available

    if not (1 <= n_linear <= MAX_LINEAR) or limit > SCREENED_LIMIT or not compiler_available():
        return None
    library = load_library(_SOURCE, _FLAGS, prefix="gram_solve_", cached_only=cached_only)
    if library is None:
        return None
    function = library.casest_gram_solve
    function.restype = ctypes.c_int
    function.argtypes = [ctypes.c_void_p, ctypes.c_long, ctypes.c_long, ctypes.c_long, ctypes.c_double,
                         ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
    return GramSolver(function)
