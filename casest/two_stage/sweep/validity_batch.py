"""The paper's validity conditions, Eq. 17 and 18, at many candidates at once (Sec. II.C, Step 2
on every candidate of a sweep).

:func:`~casest.two_stage.sweep.analysis.validity_conditions` checks one candidate with one pass
of the model's Jacobian over the record; called once per candidate, the Python around it costs
far more than the arithmetic (950-2000 candidates of seven NIST problems: 0.3-0.7 s, against
0.01-0.3 s batched, measured on 2026-12-03 beside a test run). Here the model's
prediction and Jacobian are evaluated at every (candidate, sample) pair of a block of candidates
in one call, and each candidate's R factor of its masked ``[J1 J2]`` comes from one stacked QR, so
the conditions are the same numbers (Eq. 17's ratio, Eq. 18's smallest normalised eigenvalue of
the projected information) at a cost comparable to the sweep's. Static models only: a dynamic
model's Jacobian depends on the whole record (its sensitivities), and is checked one candidate
at a time.
"""

from __future__ import annotations

import numpy as np

from ..._casadi.sample_blocks import evaluate_samples
from ...problem.static_measurement import StaticMeasurement

__all__ = ["BATCH_VALUES", "batched_applies", "batched_conditions"]

#: Jacobian values held at once per block of candidates (4e6: 32 MB)
BATCH_VALUES = 4_000_000


def batched_applies(measurement, data) -> bool:
    """Whether :func:`batched_conditions` can check this measurement's candidates: a static model
    whose record has at least as many measured values as parameters (a square R factor) and whose
    Jacobian over the record fits in :data:`BATCH_VALUES`.

    Parameters
    ----------
    measurement : Measurement
    data : Dataset

    Returns
    -------
    bool
    """
    if not isinstance(measurement, StaticMeasurement):
        return False
    rows, n = data.n_samples * measurement.model.n_outputs, measurement.model.n_parameters
    return n <= rows and rows * n <= BATCH_VALUES


def batched_conditions(measurement: StaticMeasurement, partition, data, xi1: np.ndarray, xi2: np.ndarray,
                       steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 17's ratio and Eq. 18's smallest normalised eigenvalue at each of K candidates, as
    :func:`~casest.two_stage.sweep.analysis.validity_conditions` computes them one by one.

    Parameters
    ----------
    measurement : StaticMeasurement
        :func:`batched_applies` is true for it and ``data``.
    partition : Partition
    data : Dataset
    xi1 : ndarray, shape (K, n1)
        Each candidate's linear least-squares xi1.
    xi2 : ndarray, shape (K, n2)
        The candidates.
    steps : ndarray, shape (K, n2)
        Each candidate's half sampling step (the swept parameters' units).

    Returns
    -------
    ratio : ndarray, shape (K,)
        ``||J2 step|| / ||h||`` over the measured outputs (Eq. 17).
    eig : ndarray, shape (K,)
        The smallest eigenvalue of J2's information with J1's span projected out, normalised to
        a unit diagonal (Eq. 18); 0 where a swept parameter has no information left.
    """
    model, K = measurement.model, len(xi2)
    N, ny, n = data.n_samples, model.n_outputs, model.n_parameters
    theta = np.empty((K, n))
    theta[:, list(partition.linear_index)] = np.asarray(xi1, dtype=float).reshape(K, -1)
    theta[:, list(partition.nonlinear_index)] = np.asarray(xi2, dtype=float).reshape(K, -1)
    order = list(partition.linear_index) + list(partition.nonlinear_index)  # [J1 J2]
    mask = data.output_mask().reshape(-1).astype(float)  # sample-major, as h
    per_block = max(1, BATCH_VALUES // (N * ny * n))
    ratio, eig = np.empty(K), np.empty(K)
    for start in range(0, K, per_block):
        rows = slice(start, min(start + per_block, K))
        ratio[rows], eig[rows] = _block(model, data.signals, theta[rows], order, partition.n_linear, mask,
                                        np.asarray(steps[rows], dtype=float))
    return ratio, eig


def _block(model, signals: np.ndarray, theta: np.ndarray, order: list, n1: int, mask: np.ndarray,
           steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The conditions at a block of k candidates: h and J at every (candidate, sample) pair in one
    evaluation, then one stacked QR of the masked ``[J1 J2]``."""
    k, N, (ny, n) = len(theta), len(signals), (model.n_outputs, model.n_parameters)
    h, J = evaluate_samples(model.jacobian_function, [np.tile(signals, (k, 1)), np.repeat(theta, N, axis=0)])
    h = h.reshape(k, N * ny) * mask
    # each sample's Jacobian (ny x n) is stored column-major
    J = J.reshape(k, N, n, ny).transpose(0, 1, 3, 2).reshape(k, N * ny, n)[:, :, order] * mask[None, :, None]
    moved = np.einsum("krj,kj->kr", J[:, :, n1:], steps)
    ratio = np.sqrt(np.sum(moved ** 2, axis=1)) / np.maximum(np.sqrt(np.sum(h ** 2, axis=1)), 1e-300)
    R22 = np.linalg.qr(J, mode="r")[:, n1:, n1:]
    P = np.einsum("kij,kil->kjl", R22, R22)  # J2p' J2p, J2 without the span of J1's columns
    d = np.sqrt(np.einsum("kii->ki", P))
    informed = np.all(d > 0, axis=1)
    eig = np.zeros(k)
    if informed.any():
        dn = d[informed]
        Pn = P[informed] / (dn[:, :, None] * dn[:, None, :])
        eig[informed] = np.linalg.eigvalsh(Pn)[:, 0]
    return ratio, eig
