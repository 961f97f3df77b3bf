"""Linearised longitudinal motion of an aircraft in turbulence (a filter-error example, summary Sec. 5).

States x = [u, w, q, theta] (perturbations of the body velocities (m/s), pitch rate and
pitch attitude about trim at U0 = 40 m/s), input delta_e (rad)::

    du/dt     = X_u u + X_w w - g theta + X_de delta_e
    dw/dt     = Z_u u + Z_w w + U0 q + Z_de delta_e
    dq/dt     = M_u u + M_w w + M_q q + M_de delta_e
    dtheta/dt = q

Measured: u, w and q with sensor biases, theta, and the normal acceleration
``a_z = Z_u u + Z_w w + Z_de delta_e`` with a bias: 10 derivatives and 5 biases, 15
parameters. The simulator adds vertical and horizontal gusts as white process noise on
du/dt and dw/dt (turbulence), which output error cannot follow: the filter-error method
(:func:`casest.filter_error_estimate`) estimates the derivatives, the gust intensities and R.
A 3-2-1-1 elevator input and a doublet, 600 samples at 25 Hz (24 s).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

import casest

U0, G = 40.0, 9.80665
TRUTH = {"X_u": -0.045, "X_w": 0.036, "X_de": 0.5, "Z_u": -0.37, "Z_w": -2.0, "Z_de": -10.0,
         "M_u": 0.002, "M_w": -0.045, "M_q": -2.0, "M_de": -6.0,
         "b_u": 0.2, "b_w": -0.1, "b_q": 0.004, "b_theta": 0.01, "b_az": 0.05}
#: gust intensities (process noise on du/dt and dw/dt, (m/s^2)^2 / Hz)
TURBULENCE = {"u": 0.04, "w": 0.25}
NOISE_STD = {"u_m": 0.1, "w_m": 0.1, "q_m": 0.002, "theta_m": 0.002, "a_z_m": 0.05}
RATE, N_SAMPLES = 25.0, 600


def model() -> casest.DynamicModel:
    s = {n: ca.SX.sym(n) for n in list(TRUTH) + ["u", "w", "q", "theta", "delta_e"]}
    u, w, q, th, de = s["u"], s["w"], s["q"], s["theta"], s["delta_e"]
    rhs = {"u": s["X_u"] * u + s["X_w"] * w - G * th + s["X_de"] * de,
           "w": s["Z_u"] * u + s["Z_w"] * w + U0 * q + s["Z_de"] * de,
           "q": s["M_u"] * u + s["M_w"] * w + s["M_q"] * q + s["M_de"] * de,
           "theta": q}
    outputs = {"u_m": u + s["b_u"], "w_m": w + s["b_w"], "q_m": q + s["b_q"], "theta_m": th + s["b_theta"],
               "a_z_m": s["Z_u"] * u + s["Z_w"] * w + s["Z_de"] * de + s["b_az"]}
    P = casest.Parameter
    # bounds: three times each value either side (X_de, weakly excited by the elevator, +/- 10)
    width = {n: (10.0 if n == "X_de" else 3 * abs(v) + 0.05) for n, v in TRUTH.items()}
    params = [P(n, v - width[n], v + width[n], 0.0 if n.startswith("b_") else 0.7 * v) for n, v in TRUTH.items()]
    states = [casest.State(n, 0.0) for n in ("u", "w", "q", "theta")]
    return casest.DynamicModel(params, states, [casest.Signal("delta_e", "rad")], rhs, outputs, name="longitudinal",
                               output_units={"u_m": "m/s", "w_m": "m/s", "q_m": "rad/s", "theta_m": "rad",
                                             "a_z_m": "m/s^2"}, input_hold="zoh")


def elevator(t: np.ndarray) -> np.ndarray:
    """3-2-1-1 (unit 0.4 s, 2 deg) from 1 s, a doublet (1 s, 1.5 deg) from 12 s."""
    deg = np.pi / 180
    u = np.zeros_like(t)
    edges, signs = np.cumsum([1.0, 1.2, 0.8, 0.4, 0.4]), [1, -1, 1, -1]
    for a, b, sgn in zip(edges[:-1], edges[1:], signs):
        u[(t >= a) & (t < b)] = 2 * deg * sgn
    u[(t >= 12.0) & (t < 13.0)] = 1.5 * deg
    u[(t >= 13.0) & (t < 14.0)] = -1.5 * deg
    return u


def simulate(seed: int = 0, turbulence: dict | None = None) -> casest.Dataset:
    """600 samples with turbulence and white sensor noise; the exact discretisation of the linear
    system with the elevator held over each sample and the gusts' exact covariance (Van Loan)."""
    from scipy.linalg import expm

    gust = dict(TURBULENCE if turbulence is None else turbulence)
    c = TRUTH
    A = np.array([[c["X_u"], c["X_w"], 0.0, -G], [c["Z_u"], c["Z_w"], U0, 0.0],
                  [c["M_u"], c["M_w"], c["M_q"], 0.0], [0.0, 0.0, 1.0, 0.0]])
    B = np.array([c["X_de"], c["Z_de"], c["M_de"], 0.0])
    dt = 1.0 / RATE
    aug = np.zeros((5, 5))
    aug[:4, :4], aug[:4, 4] = A, B
    E = expm(aug * dt)
    Phi, Gamma = E[:4, :4], E[:4, 4]
    Qc = np.diag([gust["u"], gust["w"], 0.0, 0.0])
    van_loan = expm(np.block([[-A, Qc], [np.zeros((4, 4)), A.T]]) * dt)
    Qd = Phi @ van_loan[:4, 4:]
    L = np.linalg.cholesky(0.5 * (Qd + Qd.T) + 1e-18 * np.eye(4))
    rng = np.random.default_rng([seed, 404])
    t = np.arange(N_SAMPLES) / RATE
    de = elevator(t)
    x, X = np.zeros(4), []
    for k in range(N_SAMPLES):
        X.append(x.copy())
        x = Phi @ x + Gamma * de[k] + L @ rng.standard_normal(4)
    X = np.array(X)
    az = c["Z_u"] * X[:, 0] + c["Z_w"] * X[:, 1] + c["Z_de"] * de
    clean = np.column_stack([X[:, 0] + c["b_u"], X[:, 1] + c["b_w"], X[:, 2] + c["b_q"], X[:, 3] + c["b_theta"],
                             az + c["b_az"]])
    names = list(NOISE_STD)
    z = clean + rng.standard_normal(clean.shape) * np.array([NOISE_STD[n] for n in names])
    return model().dataset({"t": t, "delta_e": de, **{n: z[:, j] for j, n in enumerate(names)}})


def main(seed: int = 0):
    m = model()
    fe = casest.filter_error_estimate(m, simulate(seed), {"u": 0.1, "w": 0.1}, formulation="steady-state")
    print(fe.report())
    return fe


if __name__ == "__main__":
    main()
