"""Small dense linear algebra on CasADi SX matrices, written for the operation count of the code
CasADi generates from it: symmetric products computed on one triangle, and the Cholesky factor of
a symmetric positive definite matrix reused for its solves and its log-determinant (a general
``ca.solve`` of an SX matrix expands a QR factorisation: about twice the operations).
"""

from __future__ import annotations

import casadi as ca

__all__ = ["symmetric_product", "cholesky_solver"]


def symmetric_product(A, B):
    """``A B A'`` for a symmetric ``B``, each entry below the diagonal computed once and mirrored.

    Parameters
    ----------
    A : casadi.SX or casadi.MX, shape (m, n)
    B : casadi.SX or casadi.MX, shape (n, n)
        Symmetric (only its use in ``A B`` is read, both triangles).

    Returns
    -------
    casadi.SX or casadi.MX, shape (m, m)
        Exactly symmetric (MX: the full product, averaged with its transpose).
    """
    AB = ca.mtimes(A, B)
    if isinstance(AB, ca.MX):
        full = ca.mtimes(AB, A.T)
        return 0.5 * (full + full.T)
    m = A.size1()
    out = ca.SX(m, m)
    for i in range(m):
        for j in range(i + 1):
            value = ca.dot(AB[i, :].T, A[j, :].T)
            out[i, j] = value
            if i != j:
                out[j, i] = value
    return out


def cholesky_solver(S):
    """Solves with a symmetric positive definite ``S`` through one Cholesky factor.

    Parameters
    ----------
    S : casadi.SX, shape (k, k)

    Returns
    -------
    solve : callable
        ``B (k, p) -> S^-1 B`` by two triangular substitutions.
    half_solve : callable
        ``b (k,) -> U'^-1 b`` with ``S = U' U``: ``b' S^-1 b`` is its sum of squares.
    logdet : casadi.SX
        ``ln det S`` (twice the sum of the logarithms of the factor's diagonal).
    """
    U = ca.chol(S)  # upper triangular, S = U' U

    def solve(B):
        return ca.solve(U, ca.solve(U.T, B))

    def half_solve(b):
        return ca.solve(U.T, b)

    return solve, half_solve, 2 * ca.sum1(ca.log(ca.diag(U)))
