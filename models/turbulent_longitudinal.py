"""Nonlinear longitudinal motion of a business jet in turbulence: the filter-error practice case.

A simulated record with what flight-test records flown in turbulence have (the structure of
the HFB-320 longitudinal case of the flight-test literature: four states, eleven aerodynamic
coefficients, seven measured channels, about 600 samples at 10 Hz):

- states ``x = [V, alpha, theta, q]`` (true airspeed m/s, angle of attack rad, pitch attitude
  rad, pitch rate rad/s); inputs elevator ``delta_e`` (rad) and thrust ``F_e`` (N);
- aerodynamics ``C_D = C_D0 + C_DV V/V0 + C_Dalpha alpha``, ``C_L = C_L0 + C_LV V/V0 +
  C_Lalpha alpha``, ``C_m = C_m0 + C_mV V/V0 + C_malpha alpha + C_mq q cbar/(2 V0) +
  C_mde delta_e`` (the eleven coefficients estimated);
- measured ``V, alpha, theta, q, dq/dt, a_x, a_z`` (the accelerations are the aerodynamic and
  thrust forces over the mass);
- the turbulence as white process noise on all four state rates (``TURBULENCE``); the angle of
  attack measured with almost no noise (a vane behind a filter), so that the Kalman gain takes
  the whole alpha innovation: ``diag(K C) <= 1`` is active at the optimum;
- the innovations of ``a_x`` and ``a_z`` strongly correlated (both react to the same alpha and
  V errors), so the full and the diagonal innovation covariance give different estimators;
- ``START`` 20-40 % off the truth, where the output-error residuals (the practice algorithm's
  first R) are 10-100 times the innovation covariance at the optimum.

The record is simulated by RK4 with four substeps per sample and the turbulence held over each
substep, the model by RK4 with one step per sample: the estimator's discretisation is not the
simulator's, as on a real record.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

import casest

G, RHO, S_REF, CBAR, MASS, IY, SIGMA_T = 9.80665, 0.7920, 30.0, 2.29, 7472.0, 65000.0, 0.0524
V0 = 104.67
TRUTH = {"C_D0": 0.12, "C_DV": -0.08, "C_Dalpha": 0.30, "C_L0": -0.09, "C_LV": 0.13, "C_Lalpha": 4.50,
         "C_m0": 0.11, "C_mV": 0.003, "C_malpha": -0.98, "C_mq": -34.7, "C_mde": -1.50}
#: the practice algorithm's start: every coefficient 20-40 % off
START = {"C_D0": 0.09, "C_DV": -0.06, "C_Dalpha": 0.22, "C_L0": -0.12, "C_LV": 0.10, "C_Lalpha": 3.6,
         "C_m0": 0.08, "C_mV": 0.002, "C_malpha": -0.75, "C_mq": -25.0, "C_mde": -1.20}
#: process noise (continuous intensities, (state unit / s)^2 / Hz) of the turbulence per state
TURBULENCE = {"V": 0.01, "alpha": 4e-5, "theta": 1e-7, "q": 4e-5}
#: the start of the estimated intensities, as a user gives them
TURBULENCE_START = {"V": 4e-4, "alpha": 4e-6, "theta": 4e-4, "q": 4e-4}
NOISE_STD = {"V": 0.05, "alpha": 1e-6, "theta": 2e-4, "q": 2e-4, "q_dot": 5e-4, "a_x": 0.002, "a_z": 0.002}
RATE, N_SAMPLES, SUBSTEPS = 10.0, 601, 4
STATES = ("V", "alpha", "theta", "q")


def _rates(V, alpha, theta, q, delta_e, thrust, c):
    """State rates and the accelerations the accelerometers and the pitch-rate derivative see."""
    qbar = 0.5 * RHO * V**2
    CD = c["C_D0"] + c["C_DV"] * V / V0 + c["C_Dalpha"] * alpha
    CL = c["C_L0"] + c["C_LV"] * V / V0 + c["C_Lalpha"] * alpha
    Cm = (c["C_m0"] + c["C_mV"] * V / V0 + c["C_malpha"] * alpha + c["C_mq"] * q * CBAR / (2 * V0)
          + c["C_mde"] * delta_e)
    sin, cos = (np.sin, np.cos) if isinstance(alpha, float) else (ca.sin, ca.cos)
    sin_a, cos_a = sin(alpha), cos(alpha)
    V_dot = -qbar * S_REF / MASS * CD + G * sin(alpha - theta) + thrust / MASS * cos(alpha + SIGMA_T)
    alpha_dot = (-qbar * S_REF / (MASS * V) * CL + q + G / V * cos(alpha - theta)
                 - thrust / (MASS * V) * sin(alpha + SIGMA_T))
    q_dot = qbar * S_REF * CBAR / IY * Cm
    CX, CZ = CL * sin_a - CD * cos_a, -CL * cos_a - CD * sin_a
    a_x = qbar * S_REF / MASS * CX + thrust / MASS * cos(SIGMA_T)
    a_z = qbar * S_REF / MASS * CZ - thrust / MASS * sin(SIGMA_T)
    return (V_dot, alpha_dot, q, q_dot), (q_dot, a_x, a_z)


def model() -> casest.DynamicModel:
    """The estimation model: RK4 with one step per sample, the elevator and thrust held, the
    initial states from the first measured sample."""
    s = {n: ca.SX.sym(n) for n in list(TRUTH) + list(STATES) + ["delta_e", "F_e"]}
    (V_dot, alpha_dot, theta_dot, q_dot), (q_dot_m, a_x, a_z) = _rates(
        s["V"], s["alpha"], s["theta"], s["q"], s["delta_e"], s["F_e"], s)
    rhs = {"V": V_dot, "alpha": alpha_dot, "theta": theta_dot, "q": q_dot}
    outputs = {"V_m": s["V"], "alpha_m": s["alpha"], "theta_m": s["theta"], "q_m": s["q"], "q_dot_m": q_dot_m,
               "a_x_m": a_x, "a_z_m": a_z}
    # bounds: each coefficient within twice its magnitude either side of the truth
    params = [casest.Parameter(n, v - 2 * abs(v) - 0.01, v + 2 * abs(v) + 0.01, START[n]) for n, v in TRUTH.items()]
    states = [casest.State(n, "data") for n in STATES]
    units = {"V_m": "m/s", "alpha_m": "rad", "theta_m": "rad", "q_m": "rad/s", "q_dot_m": "rad/s^2",
             "a_x_m": "m/s^2", "a_z_m": "m/s^2"}
    return casest.DynamicModel(params, states, [casest.Signal("delta_e", "rad"), casest.Signal("F_e", "N")], rhs,
                               outputs, name="turbulent_longitudinal", output_units=units, input_hold="zoh")


def trim(c: dict | None = None) -> tuple[np.ndarray, float, float]:
    """Level flight at V0: the state, elevator (rad) and thrust (N) where every rate is zero."""
    from scipy.optimize import fsolve

    c = dict(TRUTH if c is None else c)

    def residual(z):
        alpha, delta_e, thrust = z
        rates, _ = _rates(V0, float(alpha), float(alpha), 0.0, float(delta_e), float(thrust), c)
        return [rates[0], rates[1], rates[3]]

    alpha, delta_e, thrust = fsolve(residual, [0.1, 0.0, 1e4], xtol=1e-14)
    return np.array([V0, alpha, alpha, 0.0]), float(delta_e), float(thrust)


def elevator(t: np.ndarray) -> np.ndarray:
    """A 3-2-1-1 (unit 1 s, 2 deg) from 2 s and a doublet (1.5 deg, 2 s) from 30 s about trim."""
    deg = np.pi / 180
    u = np.zeros_like(t)
    edges = np.cumsum([2.0, 3.0, 2.0, 1.0, 1.0])
    for a, b, sign in zip(edges[:-1], edges[1:], [1, -1, 1, -1]):
        u[(t >= a) & (t < b)] = 2 * deg * sign
    u[(t >= 30.0) & (t < 32.0)], u[(t >= 32.0) & (t < 34.0)] = 1.5 * deg, -1.5 * deg
    return u


def simulate(seed: int = 0, turbulence: dict | None = None, n_samples: int = N_SAMPLES) -> casest.Dataset:
    """The record: RK4 with ``SUBSTEPS`` substeps per sample, white turbulence held over each substep
    (its intensity over the substep's length), white sensor noise on every channel."""
    c, gust = TRUTH, dict(TURBULENCE if turbulence is None else turbulence)
    x_trim, de_trim, thrust = trim(c)
    rng = np.random.default_rng([seed, 320])
    dt = 1.0 / RATE
    h = dt / SUBSTEPS
    t = np.arange(n_samples) * dt
    de = de_trim + elevator(t)
    gust_std = np.sqrt(np.array([gust.get(n, 0.0) for n in STATES]) / h)

    def f(x, u, w):
        rates, _ = _rates(*x, u, thrust, c)
        return np.array(rates) + w

    x, X = x_trim.copy(), []
    for k in range(n_samples):
        X.append(x.copy())
        for _ in range(SUBSTEPS):
            w = gust_std * rng.standard_normal(4)
            k1 = f(x, de[k], w)
            k2 = f(x + 0.5 * h * k1, de[k], w)
            k3 = f(x + 0.5 * h * k2, de[k], w)
            k4 = f(x + h * k3, de[k], w)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    X = np.array(X)
    outputs = np.array([_rates(*x, u, thrust, c)[1] for x, u in zip(X, de)])
    clean = np.column_stack([X, outputs])
    names = ["V_m", "alpha_m", "theta_m", "q_m", "q_dot_m", "a_x_m", "a_z_m"]
    z = clean + rng.standard_normal(clean.shape) * np.array(list(NOISE_STD.values()))
    columns = {"t": t, "delta_e": de, "F_e": np.full(n_samples, thrust)}
    columns.update({n: z[:, j] for j, n in enumerate(names)})
    columns.update({s: z[:, j] for j, s in enumerate(STATES)})  # the first sample starts the states
    return model().dataset(columns)


def main(seed: int = 0):
    m = model()
    fe = casest.filter_error_estimate(m, simulate(seed), TURBULENCE_START, start=START, formulation="innovation")
    print(fe.report())
    return fe


if __name__ == "__main__":
    main()
