"""A hand-written EKF peer of the 9-state aircraft model (``models/aircraft.py``'s
``output_error_model``: body velocities, rates and Euler angles driven by the controls, twelve
measured outputs), compiled with numba, for ``bench_export_c.py --model aircraft``.

Written as a careful user writes a filter by hand for this one model: the right-hand side of
Eq. 6.16-6.22 with its 9 x 9 Jacobian derived by hand (the chain rule through airspeed, angle of
attack and sideslip), RK4 with its tangent (the exact derivative of the step, as casest's), the
inputs linear between samples, the trapezoidal discrete process noise, and the Joseph update with
a Cholesky factor of the 12 x 12 innovation covariance; loops over preallocated arrays, no
allocation inside the record's loop. It is the same filter as ``casest.ExtendedKalmanFilter`` on
that model (its states agree to 1e-9, checked by the benchmark). Needs numba.
"""

from __future__ import annotations

import numpy as np

from casest.apps.sim import aircraft as ac

#: the constants the pass reads: gravity, air density, wing area, span, chord, mass
CONSTANTS = np.array([ac.G, ac.AIRFRAME.rho, ac.AIRFRAME.S, ac.AIRFRAME.b, ac.AIRFRAME.cbar, ac.AIRFRAME.mass])


def coefficient_vector(theta: dict) -> np.ndarray:
    """The 32 aerodynamic coefficients in ``ac.COEFFICIENTS`` order, shape (32,)."""
    return np.array([theta[k] for k in ac.COEFFICIENTS], dtype=float)


def bias_vector(theta: dict) -> np.ndarray:
    """The IMU biases (l_x, l_y, l_z, l_p, l_q, l_r), shape (6,)."""
    return np.array([theta[k] for k in ("l_x", "l_y", "l_z", "l_p", "l_q", "l_r")], dtype=float)


def ekf_pass_factory():
    """The compiled pass ``(Y (N, 12), U (N, 4), dt, c (32,), bias (6,), Qc (9, 9), R (12, 12),
    x0 (9,), P0 (9, 9)) -> x (N, 9)``: x(k|k) at every sample."""
    from numba import njit

    consts = CONSTANTS.copy()
    inertia = ac.AIRFRAME.inertia.copy()
    inertia_inv = np.linalg.inv(inertia)

    @njit(cache=False)
    def aero(x, uc, c, f, grad, dC, FM, dFM, dg):
        """The right-hand side f (9,) and its Jacobian grad (9, 9) at (x, uc); on return FM (6,) holds
        the specific forces and the moments' right-hand sides and dFM (6, 9) their gradients (dC (6, 6)
        and dg (3, 3) are work arrays)."""
        G, rho, S, b, cbar, m = consts[0], consts[1], consts[2], consts[3], consts[4], consts[5]
        u, v, w, p, q, r, phi, th = x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7]
        de, da, dr, Tc = uc[0], uc[1], uc[2], uc[3]
        V2 = u * u + v * v + w * w
        V = np.sqrt(V2)
        uw2 = u * u + w * w
        alpha = np.arctan2(w, u)
        s = v / V
        beta = np.arcsin(s)
        # d(V, alpha, beta) / d(u, v, w)
        dV = (u / V, v / V, w / V)
        da_ = (-w / uw2, 0.0, u / uw2)
        k = 1.0 / np.sqrt(1.0 - s * s)
        V3 = V2 * V
        db_ = (-k * v * u / V3, k * (1.0 / V - v * v / V3), -k * v * w / V3)
        qn, pn, rn = q * cbar / V, p * b / (2.0 * V), r * b / (2.0 * V)
        CX = c[0] + c[1] * alpha + c[2] * alpha * alpha + c[3] * qn + c[4] * de + c[5] * Tc
        CY = c[6] + c[7] * beta + c[8] * pn + c[9] * rn + c[10] * da + c[11] * dr
        CZ = c[12] + c[13] * alpha + c[14] * qn + c[15] * de
        Cl = c[16] + c[17] * beta + c[18] * pn + c[19] * rn + c[20] * da + c[21] * dr
        Cm = c[22] + c[23] * alpha + c[24] * qn + c[25] * de
        Cn = c[26] + c[27] * beta + c[28] * pn + c[29] * rn + c[30] * da + c[31] * dr
        # partials of each coefficient: (alpha, beta, V through pn qn rn, p, q, r)
        # rows CX CY CZ Cl Cm Cn; columns alpha, beta, V, p, q, r
        for i in range(6):
            for j in range(6):
                dC[i, j] = 0.0
        dC[0, 0] = c[1] + 2.0 * c[2] * alpha
        dC[0, 2] = -c[3] * qn / V
        dC[0, 4] = c[3] * cbar / V
        dC[1, 1] = c[7]
        dC[1, 2] = -(c[8] * pn + c[9] * rn) / V
        dC[1, 3] = c[8] * b / (2.0 * V)
        dC[1, 5] = c[9] * b / (2.0 * V)
        dC[2, 0] = c[13]
        dC[2, 2] = -c[14] * qn / V
        dC[2, 4] = c[14] * cbar / V
        dC[3, 1] = c[17]
        dC[3, 2] = -(c[18] * pn + c[19] * rn) / V
        dC[3, 3] = c[18] * b / (2.0 * V)
        dC[3, 5] = c[19] * b / (2.0 * V)
        dC[4, 0] = c[23]
        dC[4, 2] = -c[24] * qn / V
        dC[4, 4] = c[24] * cbar / V
        dC[5, 1] = c[27]
        dC[5, 2] = -(c[28] * pn + c[29] * rn) / V
        dC[5, 3] = c[28] * b / (2.0 * V)
        dC[5, 5] = c[29] * b / (2.0 * V)
        qS = 0.5 * rho * V2 * S
        dqS = rho * V * S  # d qS / dV
        coef = (CX, CY, CZ, Cl, Cm, Cn)
        scale = (1.0 / m, 1.0 / m, 1.0 / m, b, cbar, b)
        # forces and moments (6) and their gradients over the 9 states
        for i in range(6):
            for j in range(9):
                dFM[i, j] = 0.0
            FM[i] = qS * coef[i] * scale[i]
            for j in range(3):
                dCj = dC[i, 0] * da_[j] + dC[i, 1] * db_[j] + dC[i, 2] * dV[j]
                dFM[i, j] = (dqS * dV[j] * coef[i] + qS * dCj) * scale[i]
            for j in range(3):
                dFM[i, 3 + j] = qS * dC[i, 3 + j] * scale[i]
        sph, cph, sth, cth = np.sin(phi), np.cos(phi), np.sin(th), np.cos(th)
        for i in range(9):
            for j in range(9):
                grad[i, j] = 0.0
        # translational: Eq. 6.16-6.18
        f[0] = FM[0] - q * w + r * v - G * sth
        f[1] = FM[1] - r * u + p * w + G * cth * sph
        f[2] = FM[2] - p * v + q * u + G * cth * cph
        for j in range(6):
            grad[0, j] = dFM[0, j]
            grad[1, j] = dFM[1, j]
            grad[2, j] = dFM[2, j]
        grad[0, 2] -= q
        grad[0, 1] += r
        grad[0, 4] -= w
        grad[0, 5] += v
        grad[0, 7] = -G * cth
        grad[1, 0] -= r
        grad[1, 2] += p
        grad[1, 3] += w
        grad[1, 5] -= u
        grad[1, 7] = -G * sth * sph
        grad[1, 6] = G * cth * cph
        grad[2, 1] -= p
        grad[2, 0] += q
        grad[2, 3] -= v
        grad[2, 4] += u
        grad[2, 7] = -G * sth * cph
        grad[2, 6] = -G * cth * sph
        # rotational: omega_dot = I^-1 (M - omega x I omega)
        Io = (inertia[0, 0] * p + inertia[0, 1] * q + inertia[0, 2] * r,
              inertia[1, 0] * p + inertia[1, 1] * q + inertia[1, 2] * r,
              inertia[2, 0] * p + inertia[2, 1] * q + inertia[2, 2] * r)
        gyro = (q * Io[2] - r * Io[1], r * Io[0] - p * Io[2], p * Io[1] - q * Io[0])
        # d(omega x I omega)/d omega = [omega]x I - [I omega]x
        for j in range(3):
            dg[0, j] = q * inertia[2, j] - r * inertia[1, j]
            dg[1, j] = r * inertia[0, j] - p * inertia[2, j]
            dg[2, j] = p * inertia[1, j] - q * inertia[0, j]
        dg[0, 1] += Io[2]
        dg[0, 2] -= Io[1]
        dg[1, 0] -= Io[2]
        dg[1, 2] += Io[0]
        dg[2, 0] += Io[1]
        dg[2, 1] -= Io[0]
        for i in range(3):
            acc = 0.0
            for k2 in range(3):
                acc += inertia_inv[i, k2] * (FM[3 + k2] - gyro[k2])
            f[3 + i] = acc
            for j in range(6):
                acc = 0.0
                for k2 in range(3):
                    acc += inertia_inv[i, k2] * (dFM[3 + k2, j] - (dg[k2, j - 3] if j >= 3 else 0.0))
                grad[3 + i, j] = acc
        # Euler angles: Eq. 6.20-6.22
        tth = sth / cth
        f[6] = p + q * sph * tth + r * cph * tth
        f[7] = q * cph - r * sph
        f[8] = (q * sph + r * cph) / cth
        grad[6, 3] = 1.0
        grad[6, 4] = sph * tth
        grad[6, 5] = cph * tth
        grad[6, 6] = q * cph * tth - r * sph * tth
        grad[6, 7] = (q * sph + r * cph) / (cth * cth)
        grad[7, 4] = cph
        grad[7, 5] = -sph
        grad[7, 6] = -q * sph - r * cph
        grad[8, 4] = sph / cth
        grad[8, 5] = cph / cth
        grad[8, 6] = (q * cph - r * sph) / cth
        grad[8, 7] = (q * sph + r * cph) * sth / (cth * cth)

    @njit(cache=False)
    def ekf_pass(Y, U, dt, c, bias, Qc, R, x0, P0):
        n_samples = Y.shape[0]
        out = np.empty((n_samples, 9))
        x = x0.copy()
        P = P0.copy()
        f = np.empty(9)
        A = np.empty((9, 9))
        h = np.empty(12)
        H = np.zeros((12, 9))
        S = np.empty((12, 12))
        L = np.empty((12, 12))
        PHt = np.empty((9, 12))
        K = np.empty((9, 12))
        Z = np.empty((12, 9))
        M = np.empty((9, 9))
        T = np.empty((9, 9))
        xs = np.empty(9)
        Fs = np.empty((9, 9))
        kx = np.empty((4, 9))
        kF = np.empty((4, 9, 9))
        uc = np.empty(4)
        dC, FM, dFM, dg = np.empty((6, 6)), np.empty(6), np.empty((6, 9)), np.empty((3, 3))
        for step in range(n_samples):
            # -- measurement: V, alpha, beta, rates + bias, Euler angles, specific forces + bias
            aero(x, U[step], c, f, A, dC, FM, dFM, dg)
            u, v, w = x[0], x[1], x[2]
            V2 = u * u + v * v + w * w
            V = np.sqrt(V2)
            uw2 = u * u + w * w
            sv = v / V
            kb = 1.0 / np.sqrt(1.0 - sv * sv)
            h[0], h[1], h[2] = V, np.arctan2(w, u), np.arcsin(sv)
            for i in range(3):
                h[3 + i] = x[3 + i] + bias[3 + i]
                h[6 + i] = x[6 + i]
                h[9 + i] = FM[i] + bias[i]
            for i in range(12):
                for j in range(9):
                    H[i, j] = 0.0
            H[0, 0], H[0, 1], H[0, 2] = u / V, v / V, w / V
            H[1, 0], H[1, 2] = -w / uw2, u / uw2
            V3 = V2 * V
            H[2, 0], H[2, 1], H[2, 2] = -kb * v * u / V3, kb * (1.0 / V - v * v / V3), -kb * v * w / V3
            for i in range(6):
                H[3 + i, 3 + i] = 1.0
            for i in range(3):
                for j in range(9):
                    H[9 + i, j] = dFM[i, j]
            # -- Joseph update: S = H P H' + R, K = P H' S^-1 (Cholesky), P = (I - K H) P (I - K H)' + K R K'
            for i in range(9):
                for j in range(12):
                    acc = 0.0
                    for k2 in range(9):
                        acc += P[i, k2] * H[j, k2]
                    PHt[i, j] = acc
            for i in range(12):
                for j in range(i + 1):
                    acc = R[i, j]
                    for k2 in range(9):
                        acc += H[i, k2] * PHt[k2, j]
                    S[i, j] = acc
                    S[j, i] = acc
            for j in range(12):
                acc = S[j, j]
                for k2 in range(j):
                    acc -= L[j, k2] * L[j, k2]
                L[j, j] = np.sqrt(acc)
                for i in range(j + 1, 12):
                    acc = S[i, j]
                    for k2 in range(j):
                        acc -= L[i, k2] * L[j, k2]
                    L[i, j] = acc / L[j, j]
            for i in range(9):  # K = PHt S^-1: solve L L' K' = PHt'
                for j in range(12):
                    acc = PHt[i, j]
                    for k2 in range(j):
                        acc -= L[j, k2] * K[i, k2]
                    K[i, j] = acc / L[j, j]
                for j in range(11, -1, -1):
                    acc = K[i, j]
                    for k2 in range(j + 1, 12):
                        acc -= L[k2, j] * K[i, k2]
                    K[i, j] = acc / L[j, j]
            for i in range(9):
                acc = 0.0
                for j in range(12):
                    acc += K[i, j] * (Y[step, j] - h[j])
                xs[i] = x[i] + acc
            for i in range(9):
                for j in range(9):
                    acc = 1.0 if i == j else 0.0
                    for k2 in range(12):
                        acc -= K[i, k2] * H[k2, j]
                    M[i, j] = acc
            for i in range(9):
                for j in range(9):
                    acc = 0.0
                    for k2 in range(9):
                        acc += M[i, k2] * P[k2, j]
                    T[i, j] = acc
            for i in range(12):
                for j in range(9):
                    acc = 0.0
                    for k2 in range(12):
                        acc += R[i, k2] * K[j, k2]
                    Z[i, j] = acc
            for i in range(9):
                for j in range(i + 1):
                    acc = 0.0
                    for k2 in range(9):
                        acc += T[i, k2] * M[j, k2]
                    for k2 in range(12):
                        acc += K[i, k2] * Z[k2, j]
                    P[i, j] = acc
                    P[j, i] = acc
            for i in range(9):
                x[i] = xs[i]
                out[step, i] = x[i]
            if step == n_samples - 1:
                break
            # -- propagation: RK4 with its tangent, inputs linear between samples
            for s_ in range(4):
                frac = (0.0, 0.5, 0.5, 1.0)[s_]
                for j in range(4):
                    uc[j] = (1.0 - frac) * U[step, j] + frac * U[step + 1, j]
                if s_ == 0:
                    for i in range(9):
                        xs[i] = x[i]
                        for j in range(9):
                            Fs[i, j] = 1.0 if i == j else 0.0
                else:
                    a = 0.5 * dt if s_ < 3 else dt
                    for i in range(9):
                        xs[i] = x[i] + a * kx[s_ - 1, i]
                        for j in range(9):
                            Fs[i, j] = (1.0 if i == j else 0.0) + a * kF[s_ - 1, i, j]
                aero(xs, uc, c, f, A, dC, FM, dFM, dg)
                for i in range(9):
                    kx[s_, i] = f[i]
                    for j in range(9):
                        acc = 0.0
                        for k2 in range(9):
                            acc += A[i, k2] * Fs[k2, j]
                        kF[s_, i, j] = acc
            for i in range(9):
                x[i] = x[i] + dt / 6.0 * (kx[0, i] + 2.0 * kx[1, i] + 2.0 * kx[2, i] + kx[3, i])
                for j in range(9):
                    Fs[i, j] = (1.0 if i == j else 0.0) + dt / 6.0 * (
                        kF[0, i, j] + 2.0 * kF[1, i, j] + 2.0 * kF[2, i, j] + kF[3, i, j])
            # P = F P F' + 0.5 dt (F Qc F' + Qc)
            for i in range(9):
                for j in range(9):
                    acc = 0.0
                    for k2 in range(9):
                        acc += Fs[i, k2] * (P[k2, j] + 0.5 * dt * Qc[k2, j])
                    T[i, j] = acc
            for i in range(9):
                for j in range(i + 1):
                    acc = 0.5 * dt * Qc[i, j]
                    for k2 in range(9):
                        acc += T[i, k2] * Fs[j, k2]
                    P[i, j] = acc
                    P[j, i] = acc
        return out

    return ekf_pass
