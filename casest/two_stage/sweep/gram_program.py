"""What the sweep builds from a split's A(x, xi2) and b(x, xi2) alone, whatever the data: the
per-sample Gram entries of [A, z - b] with their data-only and candidate-only parts hoisted out,
A and b per sample, and their NumPy programs. Kept on the split (``Partition.builds``) by the
evaluators of :mod:`.evaluators`, so that every sweep of a model builds them once."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ...backend.array_sums import ArrayProgram, ArraySum
from ...problem.separate import Partition

__all__ = ["GramProgram", "channel_gram", "per_sample_A_and_b", "split_constant_entries"]


def per_sample_A_and_b(partition: Partition, n_signals: int, n_outputs: int) -> tuple:
    """One sample's A and b as one SX function and its NumPy program.

    Parameters
    ----------
    partition : Partition
    n_signals, n_outputs : int
        Columns of the data's signals and outputs.

    Returns
    -------
    per_sample : casadi.Function or None
        ``(x, xi2) -> [vec(A_k) column-major; b_k]``, shape (n_outputs (n1 + 1), 1); None where A
        or b cannot be written on SX symbols.
    program : ArrayProgram or None
        Its program over candidates x samples; None where an operation has no array form.
    """
    x, xi2 = ca.SX.sym("x", n_signals), ca.SX.sym("xi2", partition.n_nonlinear)
    try:
        A = partition.A(x, xi2) if partition.n_linear else ca.SX(n_outputs, 0)
        per_sample = ca.Function("Ab_i", [x, xi2], [ca.densify(ca.vertcat(ca.vec(A), partition.b(x, xi2)))])
    except RuntimeError:  # A or b not expressible on SX symbols
        return None, None
    return per_sample, ArrayProgram.of(per_sample, 1)


def channel_gram(partition: Partition, x, z, xi2, masked: bool):
    """One sample's Gram entries per channel: the upper triangle of ``[A_j y_j]' [A_j y_j]``,
    ``y = z - b``, shape (T, n_outputs) with T = (n1+1)(n1+2)/2; with ``masked`` z is
    ``[z; m]`` and a channel's entries count only where it was measured."""
    n1 = partition.n_linear
    ny = z.numel() // (2 if masked else 1)
    A = partition.A(x, xi2) if n1 else ca.SX(ny, 0)
    y = z[:ny] - partition.b(x, xi2)
    rows, cols = np.triu_indices(n1 + 1)
    gram = []
    for j in range(ny):
        m = ca.horzcat(A[j, :], y[j])
        weight = z[ny + j] if masked else 1
        gram.append(ca.vertcat(*[weight * m[a] * m[b] for a, b in zip(rows, cols)]))
    return ca.horzcat(*gram)


def split_constant_entries(gram: ca.SX) -> tuple:
    """The per-sample Gram entries (T, n_outputs) that vary between samples, as one column.

    Entries that are constant per sample (products with the zeros and ones of A, as for the
    columns of an offset) are N times that constant: they stay out of the loop over samples.

    Parameters
    ----------
    gram : casadi.SX, shape (T, n_outputs)
        One sample's Gram entries per channel (:func:`channel_gram`).

    Returns
    -------
    varying_entries : casadi.SX, column
    varying, fixed : ndarray of int
        Their indices in the flat (n_outputs * T) layout, entry t + T*j.
    fixed_per_sample : ndarray, shape (len(fixed),)
        The constant entries' value at one sample.
    """
    G = ca.densify(ca.cse(gram))
    entries = [G.nz[k] for k in range(G.nnz())]
    varying = np.array([k for k, e in enumerate(entries) if not e.is_constant()], dtype=int)
    fixed = np.array([k for k, e in enumerate(entries) if e.is_constant()], dtype=int)
    fixed_per_sample = np.array([float(ca.evalf(entries[k])) for k in fixed])
    G = ca.vertcat(*[entries[k] for k in varying]) if len(varying) else ca.SX.zeros(1)
    return G, varying, fixed, fixed_per_sample


class GramProgram:
    """What :class:`GramEvaluator` builds from a split's A and b alone, kept on the split
    (``Partition.builds``) for every sweep of the same model: the per-sample Gram entries with
    their data-only and candidate-only parts hoisted out, and their array program.

    Entries that are constant per sample (products with the zeros and ones of A, as for the
    columns of an offset) stay out of the loop over samples (``fixed``, ``fixed_per_sample``);
    ``varying`` indexes the others in the flat (n_outputs * T) layout, entry t + T*j.
    """

    def __init__(self, partition: Partition, n_signals: int, n_outputs: int, masked: bool):
        n1, n2 = partition.n_linear, partition.n_nonlinear
        x, xi2 = ca.SX.sym("x", n_signals), ca.SX.sym("xi2", n2)
        z = ca.SX.sym("z", 2 * n_outputs if masked else n_outputs)
        self.rows, self.cols = np.triu_indices(n1 + 1)
        G, self.varying, self.fixed, self.fixed_per_sample = split_constant_entries(
            channel_gram(partition, x, z, xi2, masked))
        # hoist data-only and candidate-only sub-expressions out of the candidate x sample loop
        G1, feat_sym, feat_expr = ca.extract_parametric(G, ca.vertcat(x, z), {})
        G2, cand_sym, cand_expr = ca.extract_parametric(G1, xi2, {})
        f_sym = ca.vertcat(*[ca.vec(v) for v in feat_sym]) if feat_sym else ca.SX.sym("f_unused", 1)
        f_expr = ca.vertcat(*[ca.vec(v) for v in feat_expr]) if feat_expr else ca.SX.zeros(1)
        c_sym = ca.vertcat(*[ca.vec(v) for v in cand_sym]) if cand_sym else ca.SX.sym("c_unused", 1)
        c_expr = ca.vertcat(*[ca.vec(v) for v in cand_expr]) if cand_expr else ca.SX.zeros(1)
        self.features = ca.Function("gram_features", [x, z], [f_expr], ["x", "z"], ["f"])
        self.constants = ca.Function("gram_constants", [xi2], [c_expr], ["xi2"], ["c"])
        self.per_sample = ca.Function("gram_i", [x, z, f_sym, xi2, c_sym], [G2], ["x", "z", "f", "xi2", "c"], ["G"])
        self.n_constants = c_sym.numel()
        self._array_program = None
        # the candidate-only values as NumPy operations over candidates (one empty sample of data)
        self._constants_array = ArraySum.build(
            ca.Function("gram_constants_1", [ca.SX.sym("none", 0), xi2], [ca.densify(c_expr)]), [np.zeros((1, 0))])

    def candidate_constants(self, xi2: np.ndarray) -> np.ndarray:
        """The candidate-only sub-expressions of the Gram entries.

        Parameters
        ----------
        xi2 : ndarray, shape (M, n2)
            Candidates, physical units.

        Returns
        -------
        ndarray, shape (M, n_constants)
        """
        M = xi2.shape[0]
        if M == 0:
            return np.zeros((0, self.n_constants))
        if self._constants_array is not None:
            return self._constants_array(np.ascontiguousarray(xi2, dtype=float))
        return np.asarray(self.constants.map(M)(xi2.T), dtype=float).reshape(-1, M).T

    def array_sum(self, sample_data: list) -> "ArraySum | None":
        """The per-sample entries summed as NumPy operations over the data.

        Parameters
        ----------
        sample_data : list of ndarray
            Signals (N, n_signals), outputs (N, n_z) and data-only features (N, n_f).

        Returns
        -------
        ArraySum or None
            None where an operation has no array form.
        """
        if self._array_program is None:
            self._array_program = ArrayProgram.of(self.per_sample, 3) or False
        return ArraySum.build(self.per_sample, sample_data, self._array_program) if self._array_program else None
