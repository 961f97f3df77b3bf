"""Small dense linear algebra on CasADi SX matrices, written for the operation count of the code
CasADi generates from it: symmetric products computed on one triangle, and the square-root-free
Cholesky factorisation (L D L') of a symmetric positive definite matrix reused for its solves, its
quadratic form and its log-determinant (a general ``ca.solve`` of an SX matrix expands a QR
factorisation: about twice the operations).
"""

from __future__ import annotations

import casadi as ca

__all__ = ["symmetric_product", "ldl_solver"]


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


def ldl_solver(S):
    """Solves with a symmetric positive definite ``S`` through one factorisation ``S = L D L'``
    (``L`` unit lower triangular, ``D`` diagonal).

    The square-root-free form of the Cholesky factorisation: each pivot is inverted once and every
    substitution multiplies by the inverse, so the generated code takes ``k`` divisions and no
    square root, where a Cholesky factor chains a square root and a division per pivot and divides
    once per entry and right-hand side (each costs several multiplications' latency on the hardware
    a filter runs on). A pivot that is not positive (``S`` not positive definite) makes the
    log-determinant NaN or infinite, which the callers check.

    Parameters
    ----------
    S : casadi.SX, shape (k, k)

    Returns
    -------
    solve : callable
        ``B (k, p) -> S^-1 B`` by two unit triangular substitutions and a diagonal scaling.
    quadratic : callable
        ``b (k,) -> b' S^-1 b``.
    logdet : casadi.SX
        ``ln det S`` (the sum of the logarithms of the pivots).
    pivots : casadi.SX, shape (k, 1)
        The pivots, the diagonal of ``D``: all positive iff ``S`` is positive definite.
    """
    k = S.size1()
    L, pivots, inverse = ca.SX.eye(k), [], []
    for j in range(k):
        LD = [L[j, i] * pivots[i] for i in range(j)]  # row j of L D
        pivots.append(S[j, j] - _sum(LD[i] * L[j, i] for i in range(j)))
        inverse.append(0.5 * (2 / pivots[j]))  # 1/d in a form CasADi does not fold back into x/d
        for r in range(j + 1, k):
            L[r, j] = (S[r, j] - _sum(L[r, i] * LD[i] for i in range(j))) * inverse[j]

    def forward(B):  # L^-1 B
        rows = []
        for i in range(k):
            rows.append(B[i, :] - _sum(L[i, j] * rows[j] for j in range(i)))
        return rows

    def solve(B):
        scaled, rows = [row * inverse[i] for i, row in enumerate(forward(B))], [None] * k
        for i in reversed(range(k)):
            rows[i] = scaled[i] - _sum(L[j, i] * rows[j] for j in range(i + 1, k))
        return ca.vertcat(*rows)

    def quadratic(b):
        return _sum(row * row * inverse[i] for i, row in enumerate(forward(b)))

    return solve, quadratic, _sum(ca.log(d) for d in pivots), ca.vertcat(*pivots)


def _sum(terms) -> ca.SX:
    """The sum of SX ``terms``, 0 for none."""
    return sum(terms, ca.SX(0))
