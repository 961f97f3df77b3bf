"""A compiled-loop EKF peer for scripts/benchmarks/bench_filters.py: the pendulum EKF written as a
plain loop over scalars (the 2x2 matrices written out, RK4 with its tangent, Joseph update) and
compiled with numba.

It is written for this one 2-state model, with the same information as casest (the RK4 step
and its tangent, the trapezoidal discrete Q, the Joseph update): an upper bound of what a
careful user writes, showing how fast the recursion itself runs on this machine. Needs numba
(``pip install numba``); :func:`available` says whether it is installed.
"""

from __future__ import annotations

import importlib.util

import numpy as np

from filter_case import DT, G, SUBSTEPS as SUB


def available() -> bool:
    """Whether numba is installed."""
    return importlib.util.find_spec("numba") is not None


def ekf_pass_factory():
    """The compiled pass ``(Y (N, 2), U (N,), c, L, q_rate, r_var, p0) -> x (N, 2)``."""
    from numba import njit

    @njit(cache=False)  # a closure: compiled on first call in each process
    def nb_ekf(Y, U, c, L, q_rate, r_var, p0):
        n = Y.shape[0]
        out = np.empty((n, 2))
        x0, x1 = 1.0, 0.0
        P00, P01, P11 = p0, 0.0, p0
        h = DT / SUB
        for k in range(n):
            # update (Joseph form), H = [[L cos x0, 0], [L sin x0, 0]]
            s0, c0 = np.sin(x0), np.cos(x0)
            H00, H10 = L * c0, L * s0
            # S = H P H' + R
            S00 = H00 * P00 * H00 + r_var
            S01 = H00 * P00 * H10
            S11 = H10 * P00 * H10 + r_var
            # H P : rows (H00*P00, H00*P01), (H10*P00, H10*P01)
            HP00, HP01, HP10, HP11 = H00 * P00, H00 * P01, H10 * P00, H10 * P01
            det = S00 * S11 - S01 * S01
            i00, i01, i11 = S11 / det, -S01 / det, S00 / det
            # K = (S^-1 H P)'  (2x2)
            A00 = i00 * HP00 + i01 * HP10; A01 = i00 * HP01 + i01 * HP11
            A10 = i01 * HP00 + i11 * HP10; A11 = i01 * HP01 + i11 * HP11
            K00, K01, K10, K11 = A00, A10, A01, A11
            e0 = Y[k, 0] - L * s0
            e1 = Y[k, 1] + L * c0
            x0 = x0 + K00 * e0 + K01 * e1
            x1 = x1 + K10 * e0 + K11 * e1
            # I - K H ; H has zero second column
            B00 = 1.0 - (K00 * H00 + K01 * H10); B01 = 0.0
            B10 = -(K10 * H00 + K11 * H10); B11 = 1.0
            # P = B P B' + K R K'
            T00 = B00 * P00 + B01 * P01; T01 = B00 * P01 + B01 * P11
            T10 = B10 * P00 + B11 * P01; T11 = B10 * P01 + B11 * P11
            P00n = T00 * B00 + T01 * B01 + r_var * (K00 * K00 + K01 * K01)
            P01n = T00 * B10 + T01 * B11 + r_var * (K00 * K10 + K01 * K11)
            P11n = T10 * B10 + T11 * B11 + r_var * (K10 * K10 + K11 * K11)
            P00, P01, P11 = P00n, P01n, P11n
            out[k, 0], out[k, 1] = x0, x1
            if k < n - 1:
                u = U[k]
                # RK4 with tangent
                a0, a1 = x0, x1
                F00, F01, F10, F11 = 1.0, 0.0, 0.0, 1.0
                for _ in range(SUB):
                    # stage 1
                    k1a, k1b = a1, -G / L * np.sin(a0) - c * a1 + u
                    j = -G / L * np.cos(a0)
                    j1_00, j1_01, j1_10, j1_11 = F10, F11, j * F00 - c * F10, j * F01 - c * F11
                    b0, b1 = a0 + h / 2 * k1a, a1 + h / 2 * k1b
                    G00, G01, G10, G11 = F00 + h / 2 * j1_00, F01 + h / 2 * j1_01, F10 + h / 2 * j1_10, F11 + h / 2 * j1_11
                    k2a, k2b = b1, -G / L * np.sin(b0) - c * b1 + u
                    j = -G / L * np.cos(b0)
                    j2_00, j2_01, j2_10, j2_11 = G10, G11, j * G00 - c * G10, j * G01 - c * G11
                    b0, b1 = a0 + h / 2 * k2a, a1 + h / 2 * k2b
                    G00, G01, G10, G11 = F00 + h / 2 * j2_00, F01 + h / 2 * j2_01, F10 + h / 2 * j2_10, F11 + h / 2 * j2_11
                    k3a, k3b = b1, -G / L * np.sin(b0) - c * b1 + u
                    j = -G / L * np.cos(b0)
                    j3_00, j3_01, j3_10, j3_11 = G10, G11, j * G00 - c * G10, j * G01 - c * G11
                    b0, b1 = a0 + h * k3a, a1 + h * k3b
                    G00, G01, G10, G11 = F00 + h * j3_00, F01 + h * j3_01, F10 + h * j3_10, F11 + h * j3_11
                    k4a, k4b = b1, -G / L * np.sin(b0) - c * b1 + u
                    j = -G / L * np.cos(b0)
                    j4_00, j4_01, j4_10, j4_11 = G10, G11, j * G00 - c * G10, j * G01 - c * G11
                    a0 = a0 + h / 6 * (k1a + 2 * k2a + 2 * k3a + k4a)
                    a1 = a1 + h / 6 * (k1b + 2 * k2b + 2 * k3b + k4b)
                    F00 = F00 + h / 6 * (j1_00 + 2 * j2_00 + 2 * j3_00 + j4_00)
                    F01 = F01 + h / 6 * (j1_01 + 2 * j2_01 + 2 * j3_01 + j4_01)
                    F10 = F10 + h / 6 * (j1_10 + 2 * j2_10 + 2 * j3_10 + j4_10)
                    F11 = F11 + h / 6 * (j1_11 + 2 * j2_11 + 2 * j3_11 + j4_11)
                x0, x1 = a0, a1
                # P = F P F' + 0.5 dt (F Qc F' + Qc), Qc = diag(0, q)
                FP00 = F00 * P00 + F01 * P01; FP01 = F00 * P01 + F01 * P11
                FP10 = F10 * P00 + F11 * P01; FP11 = F10 * P01 + F11 * P11
                n00 = FP00 * F00 + FP01 * F01 + 0.5 * DT * (F01 * q_rate * F01)
                n01 = FP00 * F10 + FP01 * F11 + 0.5 * DT * (F01 * q_rate * F11)
                n11 = FP10 * F10 + FP11 * F11 + 0.5 * DT * (F11 * q_rate * F11 + q_rate)
                P00, P01, P11 = n00, n01, n11
        return out

    return nb_ekf
