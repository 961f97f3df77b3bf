"""Fisher information, predicted covariance and design criteria as CasADi Functions.

For outputs ``z_k = h(x_k, theta) + v_k`` with ``v_k ~ N(0, R)`` the Fisher information of
theta is ``F = sum_k w_k J_k' R^-1 J_k`` with ``J_k = dh/dtheta`` at sample k (a dynamic
model: through the simulated states) and ``w_k`` the sample's weight (1 for a recorded
sample; a design may repeat samples or manoeuvres). With R unknown its information is
decoupled from theta's (Gaussian noise whose covariance does not depend on theta), so the
Cramer-Rao covariance of theta is ``F^-1`` whether R is known or estimated. This is the
covariance the stage-2 Hessian gives at the optimum (summary Sec. 4; paper Eq. 31).

:func:`information_function` builds F, the covariance and the usual criteria as one
exact CasADi Function of the signals, theta and R, differentiable with respect to the
signals (experiment design, :mod:`casest.design`):

- D: ``ln det F`` (maximised),
- A: the trace of the covariance of ``theta / scale`` (minimised; parameters in units of
  their scales, so that the sum does not depend on units),
- E: the smallest eigenvalue of the information of ``theta / scale``,
  ``diag(scale) F diag(scale)`` (maximised),
- c: ``c' F^-1 c``, the variance of a linear combination ``c' theta``.
"""

from __future__ import annotations

from typing import Sequence

import math

import casadi as ca
import numpy as np

from ..models import Model, OptionError
from ..models.dynamic import DynamicModel
from ..problem.measurement import Measurement, as_measurement
from ..problem.noise import DiagonalNoise, NoiseModel


__all__ = ["information_function", "information_matrix", "criteria_function", "ldl_pivots", "cholesky_lower",
           "lower_triangular_inverse", "jacobi_smallest_eigenvalue", "jacobi_sweeps", "CRITERIA"]

#: Names of the design criteria, with the direction they are optimised in.
CRITERIA = {"D": "maximise ln det F", "A": "minimise trace of the scaled covariance",
            "E": "maximise the smallest eigenvalue of the scaled F", "c": "minimise the variance of c' theta"}


def cholesky_lower(F: ca.SX) -> ca.SX:
    """Lower-triangular L with ``L L' = F`` as an SX expression (F symmetric positive definite)."""
    n = F.size1()
    L = ca.SX.zeros(n, n)
    for j in range(n):
        L[j, j] = ca.sqrt(F[j, j] - sum((L[j, k] ** 2 for k in range(j)), ca.SX(0)))
        for i in range(j + 1, n):
            L[i, j] = (F[i, j] - sum((L[i, k] * L[j, k] for k in range(j)), ca.SX(0))) / L[j, j]
    return L


def lower_triangular_inverse(L: ca.SX) -> ca.SX:
    """``L^-1`` of a lower-triangular SX matrix, by forward substitution."""
    n = L.size1()
    M = ca.SX.zeros(n, n)
    for j in range(n):
        M[j, j] = 1 / L[j, j]
        for i in range(j + 1, n):
            M[i, j] = -sum((L[i, k] * M[k, j] for k in range(j, i)), ca.SX(0)) / L[i, i]
    return M


def ldl_pivots(F: ca.SX) -> ca.SX:
    """The pivots d of ``F = L D L'`` (unit L), shape (n, 1): all positive iff F is positive
    definite. Smooth (rational) in F, so ``pivots(F - t I) >= 0`` states ``lambda_min(F) >= t``
    in a form IPOPT can use (the E criterion)."""
    n = F.size1()
    L = ca.SX.eye(n)
    d = []
    for j in range(n):
        dj = F[j, j] - sum((L[j, k] ** 2 * d[k] for k in range(j)), ca.SX(0))
        d.append(dj)
        for i in range(j + 1, n):
            L[i, j] = (F[i, j] - sum((L[i, k] * L[j, k] * d[k] for k in range(j)), ca.SX(0))) / dj
    return ca.vertcat(*d)


def jacobi_sweeps(n: int) -> int:
    """Cyclic Jacobi sweeps unrolled for an n x n matrix: enough for the smallest eigenvalue to
    agree with LAPACK's to a few eps times the largest (measured on graded matrices with
    eigenvalues spread over 1e20 up to n = 10; tests/test_design.py).

    Parameters
    ----------
    n : int
        The matrix's order.

    Returns
    -------
    int
    """
    return 8 + math.ceil(math.log2(max(n, 2)))


def _jacobi_sweep(n: int) -> ca.Function:
    """One cyclic sweep of Jacobi rotations ``A -> J' A J`` of a symmetric n x n matrix (cached by n).

    Each rotation zeroes ``a_pq`` (Golub and Van Loan, Alg. 8.5.2, with ``t`` written without
    dividing by ``a_pq``, so that a zero off-diagonal entry gives ``t = 0`` and finite derivatives)."""
    if n not in _SWEEPS:
        A = ca.SX.sym("A", n, n)
        a = [[A[i, j] for j in range(n)] for i in range(n)]
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq, h = a[p][q], 0.5 * (a[q][q] - a[p][p])
                denominator = ca.fabs(h) + ca.sqrt(h * h + apq * apq)
                t = ca.if_else(h >= 0, 1, -1) * apq / ca.if_else(denominator == 0, 1, denominator)
                c = 1 / ca.sqrt(1 + t * t)
                s = t * c
                for k in range(n):
                    if k not in (p, q):
                        akp, akq = a[k][p], a[k][q]
                        a[k][p] = a[p][k] = c * akp - s * akq
                        a[k][q] = a[q][k] = s * akp + c * akq
                a[p][p], a[q][q] = a[p][p] - t * apq, a[q][q] + t * apq
                a[p][q] = a[q][p] = ca.SX(0)
        _SWEEPS[n] = ca.Function(f"jacobi_sweep_{n}", [A], [ca.blockcat(a)])
    return _SWEEPS[n]


_SWEEPS: dict = {}


def jacobi_smallest_eigenvalue(F: ca.SX) -> ca.SX:
    """``lambda_min`` of a symmetric SX matrix by unrolled cyclic Jacobi sweeps (:func:`jacobi_sweeps`).

    Pure CasADi, so a Function with it can be saved, loaded and code-generated; its derivatives
    of every order are those of the rotations (the first, ``v v'`` with v the unit eigenvector,
    to rounding where the smallest eigenvalue is simple).

    Parameters
    ----------
    F : casadi.SX, shape (n, n)
        Symmetric.

    Returns
    -------
    casadi.SX, scalar
    """
    n = F.size1()
    sweep, A = _jacobi_sweep(n), F
    for _ in range(jacobi_sweeps(n)):
        A = sweep(A)
    return ca.mmin(ca.diag(A))


def criteria_function(n: int, scale=None, smallest_eigenvalue: bool = True) -> ca.Function:
    """``(F[n x n], c[n]) -> (cov, D, A, E, c_var)`` from a Fisher information matrix.

    Parameters
    ----------
    n : int
        Number of parameters.
    scale : array_like, shape (n,), optional
        Parameter scales for A and E (default ones).
    smallest_eigenvalue : bool
        Include E (unrolled Jacobi sweeps, :func:`jacobi_smallest_eigenvalue`); without it the
        outputs are ``(cov, D, A, c_var)``. Either way the Function is pure CasADi: it can be
        saved, loaded and code-generated.

    Returns
    -------
    casadi.Function
        ``cov = F^-1`` (units of theta squared), ``D = ln det F``, ``A = trace(S^-1 cov S^-1)``,
        ``E = lambda_min(S F S)`` (S = diag(scale)), ``c_var = c' cov c``. F must be
        positive definite (else the outputs are NaN: some parameter combination is not
        identified by the experiment).
    """
    scale = np.ones(n) if scale is None else np.asarray(scale, dtype=float)
    F = ca.SX.sym("F", n, n)
    c = ca.SX.sym("c", n)
    Fs = 0.5 * (F + F.T)
    L = cholesky_lower(Fs)
    M = lower_triangular_inverse(L)  # F^-1 = M' M
    cov = ca.mtimes(M.T, M)
    D = 2 * ca.sum1(ca.log(ca.diag(L)))
    Ms = M * ca.repmat(ca.DM(1.0 / scale).T, n, 1)  # trace(S^-1 M' M S^-1) = ||M S^-1||^2
    A = ca.sumsqr(Ms)
    c_var = ca.sumsqr(ca.mtimes(M, c))
    if not smallest_eigenvalue:
        return ca.Function("criteria", [F, c], [cov, D, A, c_var], ["F", "c"], ["cov", "D", "A", "c_var"])
    E = jacobi_smallest_eigenvalue(Fs * ca.DM(np.outer(scale, scale)))
    return ca.Function("criteria", [F, c], [cov, D, A, E, c_var], ["F", "c"], ["cov", "D", "A", "E", "c_var"])


#: the design criteria :func:`information_function` can return, and their output names
_CRITERION_OUTPUTS = {"D": "D", "A": "A", "E": "E", "c": "c_var"}


def information_function(model: Model | DynamicModel | Measurement, n_samples: int | Sequence[int], *,
                         name: str = "information", noise: NoiseModel | None = None,
                         criteria: Sequence[str] = ("D", "A", "E", "c")) -> ca.Function:
    """Fisher information, covariance and design criteria as one CasADi Function.

    Parameters
    ----------
    model : Model or DynamicModel
    n_samples : int, or sequence of int
        N of the experiment, or of each of several experiments (their information adds up;
        each has its own signals, noise R and weights, theta is shared).
    name : str
        The Function's name.
    noise : NoiseModel, optional
        How R enters: the input ``R`` is the n_y variances of a diagonal R (default,
        :class:`DiagonalNoise` or :class:`KnownNoise`) or the full n_y x n_y covariance
        (:class:`CorrelatedNoise`).
    criteria : sequence of {"D", "A", "E", "c"}
        The criteria among the outputs (default all four). E (the smallest eigenvalue) comes
        from unrolled cyclic Jacobi sweeps (:func:`jacobi_smallest_eigenvalue`), whose graph
        grows as n^3 (a Function without E builds faster for many parameters). The Function is
        pure CasADi: it can be saved (``Function.save``, ``casadi.Function.load``) and
        code-generated.

    Returns
    -------
    casadi.Function
        Inputs (names; one set per experiment, suffixed ``_1, _2, ...`` when there are
        several):

        - static model: ``signals`` (n_signals x N), a dynamic model: ``t`` (1 x N, s),
          ``inputs`` (n_inputs x N) and, when the model takes initial states from the data,
          ``x0_data``;
        - ``R``: noise variances (n_y,) in output units squared, or the full covariance;
        - ``weights`` (1 x N): each sample's weight (default 1);
        - ``theta`` (n_parameters,): where the information is evaluated (physical units);
        - ``c`` (n_parameters,): the linear combination for ``c_var`` (default 0).

        Outputs: ``F`` (n x n), ``cov`` (``F^-1``), ``D``, ``A``, ``E``, ``c_var`` (see the
        module docstring; A and E in units of ``model.scales``). Exact (E to a few eps times
        the largest eigenvalue), and differentiable with respect to every input (E where the
        smallest eigenvalue is simple).
    """
    sizes = [int(n_samples)] if np.isscalar(n_samples) else [int(k) for k in n_samples]
    if not sizes or min(sizes) < 1:
        raise OptionError(f"n_samples must be positive, got {n_samples!r}")
    term = (DiagonalNoise() if noise is None else noise).term
    measurement = as_measurement(model)
    model = measurement.model
    theta = ca.MX.sym("theta", model.n_parameters)
    inputs, names, F = [], [], ca.MX.zeros(model.n_parameters, model.n_parameters)
    defaults = []
    for k, N in enumerate(sizes):
        suffix = "" if len(sizes) == 1 else f"_{k + 1}"
        own, F_k = measurement.information_expression(N, term, theta)
        F = F + F_k
        inputs += [a for _, a in own]
        names += [label + suffix for label, _ in own]
        defaults += [1.0 if label == "weights" else 0.0 for label, _ in own]
    unknown = [k for k in criteria if k not in _CRITERION_OUTPUTS]
    if unknown:
        raise OptionError(f"unknown design criteria {unknown}; choose among {list(_CRITERION_OUTPUTS)}")
    c = ca.MX.sym("c", model.n_parameters)
    values = criteria_function(model.n_parameters, model.scales, smallest_eigenvalue="E" in criteria)(F=F, c=c)
    chosen = [_CRITERION_OUTPUTS[k] for k in _CRITERION_OUTPUTS if k in criteria]
    return ca.Function(name, inputs + [theta, c], [F, values["cov"]] + [values[k] for k in chosen],
                       names + ["theta", "c"], ["F", "cov"] + chosen, {"default_in": defaults + [0.0, 0.0]})


def information_matrix(model: Model | DynamicModel | Measurement, data, theta, R, weights=None) -> np.ndarray:
    """The Fisher information of theta for recorded signals, numerically.

    Parameters
    ----------
    model : Model or DynamicModel
    data : Dataset, or sequence of Dataset
        The experiment(s) (outputs are not used; missing outputs carry no information).
    theta : array_like, shape (n_parameters,), or mapping
    R : array_like
        Noise variances, shape (n_outputs,), or a full covariance (n_outputs, n_outputs);
        one for all experiments, or a sequence with one per experiment.
    weights : array_like, shape (N,), optional
        Sample weights (one experiment only).

    Returns
    -------
    ndarray, shape (n_parameters, n_parameters)
    """
    experiments = list(data) if isinstance(data, (list, tuple)) else [data]
    Rs = list(R) if isinstance(R, (list, tuple)) else [R] * len(experiments)
    if len(Rs) != len(experiments):
        raise OptionError(f"{len(Rs)} noise R for {len(experiments)} experiments")
    measurement = as_measurement(model)
    model = measurement.model
    theta = model.vector(theta)
    n, ny = model.n_parameters, model.n_outputs
    F = np.zeros((n, n))
    for d, R_e in zip(experiments, Rs):
        _, J = measurement.prediction_and_jacobian(theta, d)
        R_e = np.asarray(R_e, dtype=float)
        W = np.linalg.inv(R_e) if R_e.ndim == 2 else np.diag(1.0 / R_e.reshape(-1))
        Jb = J.reshape(d.n_samples, ny, n)
        measured = ~np.isnan(d.outputs) if d.has_missing else np.ones((d.n_samples, ny), dtype=bool)
        Jb = Jb * measured[:, :, None]
        w = np.ones(d.n_samples) if weights is None else np.asarray(weights, dtype=float).reshape(-1)
        F += np.einsum("k,kia,ij,kjb->ab", w, Jb, W, Jb)
    return 0.5 * (F + F.T)
