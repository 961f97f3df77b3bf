"""A hand-written NumPy implementation of the textbook's filter-error algorithm in the practice
(innovation) formulation with a diagonal innovation covariance (Jategaonkar, *Flight Vehicle
System Identification*, Sec. 5.5), for the nonlinear model of ``models/turbulent_longitudinal.py``.

Written from the equations, sharing nothing with casest but the record:

- the model's rates and outputs in NumPy (complex-safe), RK4 with one step per sample and the
  inputs held; the filter ``e_k = y_k - h(x_k)``, ``x_k+1 = RK4(x_k + K e_k)``;
- A = df/dx and C = dh/dx at the first state and input by fourth-order central differences;
- P from the continuous Riccati equation ``A P + P A' - P C' R^-1 C P / dt + F F' = 0``
  (SciPy's ``solve_continuous_are``, then Newton-Kleinman steps in complex arithmetic), K = P C' R^-1;
- the innovations' derivatives by complex steps through the whole pass (gain included);
- with R held, a Gauss-Newton step on ``1/2 sum e' R^-1 e`` a round (halving the step while the
  merit rises), and once a round moves the parameters by less than 1e-4 (relative) steps until
  the predicted decrease is below 1e-20, the constraint ``diag(K C) <= 1``
  handled as the textbook does: linearised, the violated ones made active and the step
  corrected by Lagrange multipliers;
- R = diag(sum e e' / N), F compensated by Eq. 5.41, until J = N/2 ln det R moves by less
  than 1e-13 (relative) and the parameters by less than 1e-11.
"""

import numpy as np
from scipy.linalg import solve_continuous_are

STEP = 1e-30  # the complex step


def _rates(x, u, c, k):
    """Rates (..., 4) and the outputs (..., 7) of the model file's equations (complex-safe)."""
    V, alpha, theta, q = x[..., 0], x[..., 1], x[..., 2], x[..., 3]
    de, thrust = u
    qbar = 0.5 * k["RHO"] * V**2
    CD = c[..., 0] + c[..., 1] * V / k["V0"] + c[..., 2] * alpha
    CL = c[..., 3] + c[..., 4] * V / k["V0"] + c[..., 5] * alpha
    Cm = c[..., 6] + c[..., 7] * V / k["V0"] + c[..., 8] * alpha + c[..., 9] * q * k["CBAR"] / (2 * k["V0"]) + c[..., 10] * de
    m, S, g, s = k["MASS"], k["S_REF"], k["G"], k["SIGMA_T"]
    V_dot = -qbar * S / m * CD + g * np.sin(alpha - theta) + thrust / m * np.cos(alpha + s)
    alpha_dot = -qbar * S / (m * V) * CL + q + g / V * np.cos(alpha - theta) - thrust / (m * V) * np.sin(alpha + s)
    q_dot = qbar * S * k["CBAR"] / k["IY"] * Cm
    CX, CZ = CL * np.sin(alpha) - CD * np.cos(alpha), -CL * np.cos(alpha) - CD * np.sin(alpha)
    a_x = qbar * S / m * CX + thrust / m * np.cos(s)
    a_z = qbar * S / m * CZ - thrust / m * np.sin(s)
    rates = np.stack([V_dot, alpha_dot, q, q_dot], axis=-1)
    outputs = np.stack([V, alpha, theta, q, q_dot, a_x, a_z], axis=-1)
    return rates, outputs


def _jacobian(fun, x, n_out):
    """d fun / dx by fourth-order central differences (steps 1e-3 of each state's size)."""
    J = np.zeros((n_out, x.size), dtype=complex)
    for j in range(x.size):
        h = 1e-3 * max(abs(x[j].real), 1e-2)
        e = np.zeros(x.size)
        e[j] = h
        J[:, j] = (-fun(x + 2 * e) + 8 * fun(x + e) - 8 * fun(x - e) + fun(x - 2 * e)) / (12 * h)
    return J


def _riccati(A, C, f, R, dt):
    """P of A P + P A' - P C' R^-1 C P / dt + F F' = 0: SciPy on the real part, then Newton-Kleinman
    steps in complex arithmetic (each a Lyapunov equation solved by Kronecker products)."""
    n = A.shape[0]
    FF = np.diag(f**2)
    M = C.T @ np.diag(1 / R) @ C / dt
    P = solve_continuous_are(A.real.T, C.real.T, FF.real, np.diag(R.real) * dt).astype(complex)
    eye = np.eye(n)
    for _ in range(4):
        closed = A - P @ M
        L = np.kron(eye, closed) + np.kron(closed, eye)
        P = np.linalg.solve(L, -(FF + P @ M @ P).reshape(-1, order="F")).reshape(n, n, order="F")
        P = 0.5 * (P + P.T)
    return P, P @ C.T @ np.diag(1 / R)


class PracticeFilter:
    """The record and the model constants; :meth:`pass_` runs the filter for a batch of points."""

    def __init__(self, data, constants, noisy):
        self.k, self.N, self.noisy = constants, data.n_samples, list(noisy)
        self.dt = float(data.signals[1, 0] - data.signals[0, 0])
        self.U = data.signals[:, 1:3]  # delta_e, F_e
        self.Y = data.outputs
        self.x0 = data.outputs[0, :4].copy()  # the states' first measured sample

    def gain(self, w, R):
        """K, C and diag(K C) of one point ``w = [c (11); F of the noisy states]`` (complex allowed)."""
        c, u = w[:11], self.U[0]
        f = np.zeros(4, dtype=w.dtype)
        f[self.noisy] = w[11:]
        A = _jacobian(lambda x: _rates(x, u, c, self.k)[0], self.x0.astype(complex), 4)
        C = _jacobian(lambda x: _rates(x, u, c, self.k)[1], self.x0.astype(complex), 7)
        _, K = _riccati(A, C, f, R, self.dt)
        return K, C, np.diag(K @ C)

    def pass_(self, W, R):
        """Innovations (B, N, 7) and diag(K C) (B, 4) of a batch of points W (B, n_w)."""
        B = W.shape[0]
        gains = [self.gain(w, R) for w in W]
        K = np.array([g[0] for g in gains])
        c = W[:, :11]
        x = np.repeat(self.x0[None, :].astype(complex), B, axis=0)
        E = np.zeros((B, self.N, 7), dtype=complex)
        h = self.dt
        for k in range(self.N):
            u = self.U[k]
            _, y = _rates(x, u, c, self.k)
            e = self.Y[k] - y
            E[:, k] = e
            if k == self.N - 1:
                break
            x = x + np.einsum("bij,bj->bi", K, e)
            k1 = _rates(x, u, c, self.k)[0]
            k2 = _rates(x + 0.5 * h * k1, u, c, self.k)[0]
            k3 = _rates(x + 0.5 * h * k2, u, c, self.k)[0]
            k4 = _rates(x + h * k3, u, c, self.k)[0]
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return E, np.array([g[2] for g in gains])

    def derivatives(self, w, R):
        """E (N, 7), dE/dw (N, 7, n_w), diag(K C) (4,) and its Jacobian (4, n_w) by complex steps."""
        W = np.repeat(w[None, :].astype(complex), w.size, axis=0) + 1j * STEP * np.eye(w.size)
        E, kc = self.pass_(W, R)
        return E[0].real, np.transpose(E.imag / STEP, (1, 2, 0)), kc[0].real, (kc.imag / STEP).T

    def value(self, w, R):
        E, kc = self.pass_(w[None, :].astype(complex), R)
        return E[0].real, kc[0].real


def _textbook_step(M, g, kc, J):
    """The Gauss-Newton step with the linearised diag(K C) <= 1: the violated constraints made
    active and the step corrected by their Lagrange multipliers (dropping a negative one)."""
    Mi = np.linalg.inv(M)
    d = -Mi @ g
    active = []
    for _ in range(10):
        violated = [i for i in range(kc.size) if kc[i] + J[i] @ d > 1.0 + 1e-14 and i not in active]
        if not violated:
            break
        active += violated
        Ja = J[active]
        lam = np.linalg.solve(Ja @ Mi @ Ja.T, Ja @ (-Mi @ g) - (1.0 - kc[active]))
        keep = lam > 0
        active = [a for a, k in zip(active, keep) if k]
        Ja = J[active]
        d = -Mi @ g
        if active:
            d = d - Mi @ Ja.T @ np.linalg.solve(Ja @ Mi @ Ja.T, Ja @ d - (1.0 - kc[active]))
    return d


def practice_algorithm(data, constants, theta0, f0, noisy, max_rounds=80):
    """The relaxation from ``theta0`` (11) and ``f0`` (F of the ``noisy`` states; the others have
    none). Returns ``(theta, f, R)``."""
    filt = PracticeFilter(data, constants, noisy)
    N = filt.N
    w = np.concatenate([theta0, f0]).astype(float)
    E, _ = filt.value(w, np.var(data.outputs, axis=0))
    R = np.mean(E**2, axis=0)
    J_prev, previous, moved = np.inf, w.copy(), np.inf
    for _ in range(max_rounds):
        Ri = 1.0 / R
        E = None  # the innovations at w with R held, once known
        for _ in range(30 if moved < 1e-4 else 1):  # one step a round until the rounds settle, as practice does
            E_w, dE, kc, Jkc = filt.derivatives(w, R)
            E = E_w
            M = np.einsum("kiv,i,kiw->vw", dE, Ri, dE)
            g = np.einsum("kiv,i,ki->v", dE, Ri, E_w)
            d = _textbook_step(M, g, kc, Jkc)
            predicted = float(d @ M @ d)
            if predicted < 1e-20:
                break
            V = 0.5 * np.sum(E_w**2 * Ri)
            mu = 1e3 * max(1.0, abs(V))
            for halving in range(11 if predicted > 1e-12 else 1):  # below, a failed full step is rounding
                trial = w + d * 0.5**halving
                E_t, kc_t = filt.value(trial, R)
                if np.all(np.isfinite(E_t)) and (0.5 * np.sum(E_t**2 * Ri) + mu * np.sum(np.maximum(kc_t - 1, 0))
                                                  <= V + mu * np.sum(np.maximum(kc - 1, 0))):
                    w, E = trial, E_t
                    break
            else:
                break
        _, C, _ = filt.gain(w, R)
        C = C.real[:, filt.noisy]
        R_new = np.mean(E**2, axis=0)
        weight = (C**2).T @ (1 / R)
        w[11:] *= ((C**2).T @ (np.sqrt(R_new / R) / R)) / weight  # Eq. 5.41
        J = 0.5 * N * np.sum(np.log(R_new))
        moved = np.max(np.abs(w - previous) / np.maximum(np.abs(w), 1e-8))
        R, previous = R_new, w.copy()
        if abs(J - J_prev) <= 1e-13 * abs(J) and moved <= 1e-11:
            break
        J_prev = J
    return w[:11], w[11:], R
