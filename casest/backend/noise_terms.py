"""The noise covariance R's share of the ML cost, one strategy per parametrisation of R.

Paper Eq. 6 sums, per sample, ``1/2 r' R^-1 r + 1/2 ln|R|`` with the residual ``r = z - h``.
How R is parametrised in stage 2's decision vector decides that term, the length of the
noise block, and how R weighs the Jacobian in the Fisher information. Each parametrisation
is a :class:`NoiseTerm`; the sums, the NLPs and the information matrix ask it instead of
testing which one it is:

- :data:`DIAGONAL` (:class:`DiagonalTerm`): R diagonal, block ``rho = ln R`` (n_y); a missing
  output adds neither its residual nor its ``ln R_j``.
- :data:`CHOLESKY` (:class:`CholeskyTerm`): R full, ``R = L L'`` with the log-Cholesky block
  ``ell`` (:func:`casest.backend.linalg.cholesky_factor`); complete data only.

The problem layer's noise models (:mod:`casest.problem.noise`) each name their term.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .linalg import cholesky_factor, cholesky_vector, covariance_of, n_cholesky, variances_of


__all__ = ["NoiseTerm", "DiagonalTerm", "CholeskyTerm", "DIAGONAL", "CHOLESKY", "term_of_covariance"]


class NoiseTerm:
    """One parametrisation of R in the ML cost (base of :class:`DiagonalTerm`, :class:`CholeskyTerm`).

    Attributes
    ----------
    name : str
        A short label, part of the names of the per-sample functions and of cache keys.
    per_channel : bool
        The cost separates by output channel (R diagonal): each ``R_j`` has a closed-form ML
        value from its own residuals, which the reduced and alternating modes, Gauss-Newton
        output error and the Levenberg-Marquardt reweighting rely on.
    takes_mask : bool
        Samples with missing outputs can enter (an observation mask).
    full_mode_reason : str or None
        Why stage 2 must solve every parameter together (the full mode), in words for a
        note; None when the reduced and alternating modes apply.
    """

    name = ""
    per_channel = True
    takes_mask = True
    full_mode_reason: str | None = None

    def block_size(self, n_outputs: int) -> int:
        """Length of the noise block of the decision vector.

        Parameters
        ----------
        n_outputs : int

        Returns
        -------
        int
        """
        raise NotImplementedError

    def block_of(self, R) -> np.ndarray:
        """The noise block of a numeric R.

        Parameters
        ----------
        R : array_like, shape (n_outputs,) or (n_outputs, n_outputs)

        Returns
        -------
        ndarray, shape (block_size(n_outputs),)
        """
        raise NotImplementedError

    def covariance_of_block(self, block, n_outputs: int) -> np.ndarray:
        """Inverse of :meth:`block_of`: the diagonal of R, shape (n_outputs,), or the full R.

        Parameters
        ----------
        block : array_like, shape (block_size(n_outputs),)
        n_outputs : int

        Returns
        -------
        ndarray, shape (n_outputs,) or (n_outputs, n_outputs)
        """
        raise NotImplementedError

    def sample_cost(self, residual, block, mask=None):
        """One sample's ``1/2 r' R^-1 r + 1/2 ln|R|`` in terms of the noise block.

        Parameters
        ----------
        residual : casadi.SX, shape (n_outputs, 1)
            ``z - h`` of the sample.
        block : casadi.SX, shape (block_size(n_outputs), 1)
        mask : casadi.SX, shape (n_outputs, 1), optional
            1 for a measured output, 0 for a missing one.

        Returns
        -------
        casadi.SX
            Scalar.
        """
        raise NotImplementedError

    def covariance_symbol(self, n_outputs: int, name: str = "R", kind=ca.MX):
        """A symbol for R in this parametrisation's shape (diagonal: the column of variances).

        Parameters
        ----------
        n_outputs : int
        name : str
        kind : casadi.MX or casadi.SX

        Returns
        -------
        casadi.MX or casadi.SX
            Shape (n_outputs, 1) or (n_outputs, n_outputs).
        """
        raise NotImplementedError

    def inverse(self, R):
        """R^-1 in the shape of :meth:`covariance_symbol`.

        Parameters
        ----------
        R : casadi.MX or casadi.SX

        Returns
        -------
        casadi.MX or casadi.SX
        """
        raise NotImplementedError

    def weigh(self, R_inverse, jacobian):
        """``R^-1 J`` for one sample's Jacobian J (n_outputs x n).

        Parameters
        ----------
        R_inverse : casadi.SX or casadi.MX
            :meth:`inverse` of R.
        jacobian : casadi.SX or casadi.MX, shape (n_outputs, n)

        Returns
        -------
        casadi.SX or casadi.MX, shape (n_outputs, n)
        """
        raise NotImplementedError

    def information(self, jacobian: np.ndarray, R) -> np.ndarray:
        """The Gauss-Newton information ``sum_k J_k' R^-1 J_k``, numerically.

        Parameters
        ----------
        jacobian : ndarray, shape (N n_outputs, n)
            d h / d theta at every sample, sample-major (rows of a missing output zero).
        R : ndarray
            The variances (n_outputs,) or the full R (n_outputs, n_outputs).

        Returns
        -------
        ndarray, shape (n, n)
        """
        raise NotImplementedError

    def stacked_information(self, jacobian, R, weights):
        """``J' W J`` for the Jacobian of every sample stacked sample-major, W block diagonal with
        ``weights_k R^-1``.

        Parameters
        ----------
        jacobian : casadi.MX, shape (N n_outputs, n)
        R : casadi.MX
            In the shape of :meth:`covariance_symbol`.
        weights : casadi.MX, shape (1, N)

        Returns
        -------
        casadi.MX, shape (n, n)
        """
        raise NotImplementedError


@dataclass(frozen=True)
class DiagonalTerm(NoiseTerm):
    """R diagonal, block ``ln R`` (n_outputs): ``1/2 sum_j m_j (e^-rho_j r_j^2 + rho_j)``."""

    name = "ml"

    def block_size(self, n_outputs: int) -> int:
        return n_outputs

    def block_of(self, R) -> np.ndarray:
        return np.log(np.asarray(R, dtype=float).reshape(-1))

    def covariance_of_block(self, block, n_outputs: int) -> np.ndarray:
        return np.exp(np.asarray(block, dtype=float).reshape(-1))

    def sample_cost(self, residual, block, mask=None):
        if mask is None:
            return 0.5 * ca.sum1(ca.exp(-block) * residual**2) + 0.5 * ca.sum1(block)
        return 0.5 * ca.sum1(mask * ca.exp(-block) * residual**2) + 0.5 * ca.sum1(mask * block)

    def covariance_symbol(self, n_outputs: int, name: str = "R", kind=ca.MX):
        return kind.sym(name, n_outputs)

    def inverse(self, R):
        return 1 / R

    def weigh(self, R_inverse, jacobian):
        return jacobian * ca.repmat(R_inverse, 1, jacobian.size2())

    def information(self, jacobian: np.ndarray, R) -> np.ndarray:
        variances = variances_of(R)
        w = np.tile(1.0 / variances, jacobian.shape[0] // variances.size)
        return (jacobian * w[:, None]).T @ jacobian

    def stacked_information(self, jacobian, R, weights):
        N = weights.numel()
        s = ca.vec(ca.repmat(1 / R, 1, N) * ca.repmat(weights, R.numel(), 1))
        return ca.mtimes(jacobian.T, jacobian * ca.repmat(s, 1, jacobian.size2()))


@dataclass(frozen=True)
class CholeskyTerm(NoiseTerm):
    """R full, ``R = L L'``, block the log-Cholesky vector: ``1/2 ||L^-1 r||^2 + sum_j ln L_jj``."""

    name = "mlf"
    per_channel = False
    takes_mask = False
    full_mode_reason = "a full R is estimated with all of theta"

    def block_size(self, n_outputs: int) -> int:
        return n_cholesky(n_outputs)

    def block_of(self, R) -> np.ndarray:
        R = np.asarray(R, dtype=float)
        return cholesky_vector(R if R.ndim == 2 else np.diag(R))

    def covariance_of_block(self, block, n_outputs: int) -> np.ndarray:
        return covariance_of(np.asarray(block, dtype=float).reshape(-1), n_outputs)

    def sample_cost(self, residual, block, mask=None):
        if mask is not None:
            raise ValueError("a full R needs complete data (no observation mask)")
        ny = residual.numel()
        L = cholesky_factor(block, ny)
        solved = []  # forward substitution: L y = r
        for i in range(ny):
            acc = residual[i]
            for j in range(i):
                acc = acc - L[i, j] * solved[j]
            solved.append(acc / L[i, i])
        return 0.5 * ca.sumsqr(ca.vertcat(*solved)) + ca.sum1(block[:ny])

    def covariance_symbol(self, n_outputs: int, name: str = "R", kind=ca.MX):
        return kind.sym(name, n_outputs, n_outputs)

    def inverse(self, R):
        return ca.inv(R)

    def weigh(self, R_inverse, jacobian):
        return ca.mtimes(R_inverse, jacobian)

    def information(self, jacobian: np.ndarray, R) -> np.ndarray:
        R = np.asarray(R, dtype=float)
        ny = R.shape[0]
        blocks = jacobian.reshape(-1, ny, jacobian.shape[1])  # n_y rows per sample
        return np.einsum("kia,ij,kjb->ab", blocks, np.linalg.inv(R), blocks)

    def stacked_information(self, jacobian, R, weights):
        return ca.mtimes(jacobian.T, ca.mtimes(ca.kron(ca.diag(ca.vec(weights)), ca.inv(R)), jacobian))


DIAGONAL = DiagonalTerm()
CHOLESKY = CholeskyTerm()


def term_of_covariance(R) -> NoiseTerm:
    """The term of a numeric R: :data:`CHOLESKY` for a matrix, :data:`DIAGONAL` for variances.

    Parameters
    ----------
    R : ndarray, shape (n_outputs,) or (n_outputs, n_outputs)

    Returns
    -------
    NoiseTerm
    """
    return CHOLESKY if getattr(R, "ndim", 1) == 2 else DIAGONAL
