"""A rigid-aircraft simulation for the two-step method (reference summary Sec. 6.1-6.3).

The coefficient model of Eq. 6.8-6.13 (the 32 coefficients of Eq. 6.25), forces and moments
of Eq. 6.14-6.15, the equations of motion 6.16-6.22 in air-relative body velocities (with a
constant wind they keep the same form) and the position of Eq. 6.23 with the wind. A light
aircraft trimmed in level flight is flown through a 3-2-1-1 on the elevator, aileron and
rudder doublets, and multisines on all four controls; the record carries what the
instruments of Eq. 6.3 measure, with noise, IMU biases (Eq. 6.4-6.5) and a constant wind.
Body axes x forward, y right, z down; earth axes north, east, down.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np


G = 9.80665
DEG = np.pi / 180.0

#: Coefficient names in the order of Eq. 6.25.
COEFFICIENTS = ("CX0", "CXa", "CXa2", "CXq", "CXde", "CXTc", "CY0", "CYb", "CYp", "CYr", "CYda", "CYdr",
                "CZ0", "CZa", "CZq", "CZde", "Cl0", "Clb", "Clp", "Clr", "Clda", "Cldr",
                "Cm0", "Cma", "Cmq", "Cmde", "Cn0", "Cnb", "Cnp", "Cnr", "Cnda", "Cndr")

#: Values of a light aircraft (per rad; Tc is the thrust coefficient T / (q S)).
TRUE_COEFFICIENTS = {
    "CX0": -0.035, "CXa": 0.20, "CXa2": 3.0, "CXq": -0.6, "CXde": -0.05, "CXTc": 1.0,
    "CY0": 0.002, "CYb": -0.60, "CYp": -0.10, "CYr": 0.30, "CYda": -0.02, "CYdr": 0.15,
    "CZ0": -0.25, "CZa": -4.8, "CZq": -5.0, "CZde": -0.40,
    "Cl0": 0.001, "Clb": -0.08, "Clp": -0.50, "Clr": 0.10, "Clda": 0.15, "Cldr": 0.01,
    "Cm0": 0.04, "Cma": -0.80, "Cmq": -12.0, "Cmde": -1.10,
    "Cn0": -0.001, "Cnb": 0.07, "Cnp": -0.05, "Cnr": -0.12, "Cnda": -0.01, "Cndr": -0.07,
}

#: The rigid-body states (air-relative body velocity, body rates, Euler angles, NED position).
STATES = ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi", "x", "y", "z")
CONTROLS = ("de", "da", "dr", "Tc")


@dataclass(frozen=True)
class Airframe:
    """Mass (kg), wing area (m^2), span and chord (m), inertia (kg m^2), air density (kg/m^3)."""

    mass: float = 1200.0
    S: float = 16.2
    b: float = 10.9
    cbar: float = 1.5
    Ix: float = 1285.0
    Iy: float = 1825.0
    Iz: float = 2667.0
    Ixz: float = 0.0
    rho: float = 1.2

    @property
    def inertia(self) -> np.ndarray:
        return np.array([[self.Ix, 0.0, -self.Ixz], [0.0, self.Iy, 0.0], [-self.Ixz, 0.0, self.Iz]])


AIRFRAME = Airframe()


def air_data(u, v, w):
    """V, alpha, beta of the air-relative body velocity (CasADi or NumPy)."""
    lib = ca if isinstance(u, (ca.SX, ca.MX)) else np
    V = lib.sqrt(u**2 + v**2 + w**2)
    return V, lib.arctan2(w, u) if lib is np else ca.atan2(w, u), lib.arcsin(v / V) if lib is np else ca.asin(v / V)


def coefficient_expressions(alpha, beta, V, p, q, r, de, da, dr, Tc, c: dict, airframe: Airframe = AIRFRAME) -> dict:
    """C_X ... C_n of Eq. 6.8-6.13 (the roll moment without C_l_alpha, as in Eq. 6.25)."""
    qn, pn, rn = q * airframe.cbar / V, p * airframe.b / (2 * V), r * airframe.b / (2 * V)
    return {
        "CX": c["CX0"] + c["CXa"] * alpha + c["CXa2"] * alpha**2 + c["CXq"] * qn + c["CXde"] * de + c["CXTc"] * Tc,
        "CY": c["CY0"] + c["CYb"] * beta + c["CYp"] * pn + c["CYr"] * rn + c["CYda"] * da + c["CYdr"] * dr,
        "CZ": c["CZ0"] + c["CZa"] * alpha + c["CZq"] * qn + c["CZde"] * de,
        "Cl": c["Cl0"] + c["Clb"] * beta + c["Clp"] * pn + c["Clr"] * rn + c["Clda"] * da + c["Cldr"] * dr,
        "Cm": c["Cm0"] + c["Cma"] * alpha + c["Cmq"] * qn + c["Cmde"] * de,
        "Cn": c["Cn0"] + c["Cnb"] * beta + c["Cnp"] * pn + c["Cnr"] * rn + c["Cnda"] * da + c["Cndr"] * dr,
    }


def rigid_body(x: ca.SX, controls: ca.SX, c: dict, wind=(0.0, 0.0, 0.0), airframe: Airframe = AIRFRAME):
    """rhs of Eq. 6.16-6.23 and the specific force (X, Y, Z)/m, as CasADi expressions."""
    u, v, w, p, q, r, phi, theta, psi = (x[i] for i in range(9))
    de, da, dr, Tc = (controls[i] for i in range(4))
    V, alpha, beta = air_data(u, v, w)
    C = coefficient_expressions(alpha, beta, V, p, q, r, de, da, dr, Tc, c, airframe)
    qS = 0.5 * airframe.rho * V**2 * airframe.S
    m = airframe.mass
    fx, fy, fz = qS * C["CX"] / m, qS * C["CY"] / m, qS * C["CZ"] / m
    moments = ca.vertcat(qS * airframe.b * C["Cl"], qS * airframe.cbar * C["Cm"], qS * airframe.b * C["Cn"])
    omega = ca.vertcat(p, q, r)
    I = ca.DM(airframe.inertia)
    omega_dot = ca.solve(I, moments - ca.cross(omega, I @ omega))
    sph, cph, sth, cth, sps, cps = ca.sin(phi), ca.cos(phi), ca.sin(theta), ca.cos(theta), ca.sin(psi), ca.cos(psi)
    L_EB = ca.vertcat(ca.horzcat(cth * cps, sph * sth * cps - cph * sps, cph * sth * cps + sph * sps),
                      ca.horzcat(cth * sps, sph * sth * sps + cph * cps, cph * sth * sps - sph * cps),
                      ca.horzcat(-sth, sph * cth, cph * cth))
    pos_dot = L_EB @ ca.vertcat(u, v, w) + ca.DM(wind)
    rhs = ca.vertcat(
        fx - q * w + r * v - G * sth,
        fy - r * u + p * w + G * cth * sph,
        fz - p * v + q * u + G * cth * cph,
        omega_dot,
        p + q * sph * sth / cth + r * cph * sth / cth,
        q * cph - r * sph,
        (q * sph + r * cph) / cth,
        pos_dot,
    )
    return rhs, ca.vertcat(fx, fy, fz)


def _functions(c: dict, wind, airframe: Airframe):
    x, controls = ca.SX.sym("x", 12), ca.SX.sym("controls", 4)
    rhs, force = rigid_body(x, controls, c, wind, airframe)
    return ca.Function("aircraft", [x, controls], [rhs, force])


def trim(V0: float = 50.0, c: dict | None = None, airframe: Airframe = AIRFRAME) -> tuple[np.ndarray, np.ndarray]:
    """Level wings-level flight at airspeed V0: the state (12,) and controls (4,)."""
    from scipy.optimize import fsolve

    c = TRUE_COEFFICIENTS if c is None else c
    f = _functions(c, (0.0, 0.0, 0.0), airframe)

    def state(z):
        alpha, _, _ = z
        return np.array([V0 * np.cos(alpha), 0.0, V0 * np.sin(alpha), 0, 0, 0, 0, alpha, 0, 0, 0, 0])

    def residual(z):
        rhs, _ = f(state(z), [z[1], 0.0, 0.0, z[2]])
        rhs = np.asarray(rhs).ravel()
        return [rhs[0], rhs[2], rhs[4]]

    z = fsolve(residual, [0.05, 0.0, 0.03], xtol=1e-13)
    return state(z), np.array([z[1], 0.0, 0.0, z[2]])


def controls(t: np.ndarray, trim_controls: np.ndarray) -> np.ndarray:
    """The manoeuvres (N, 4): 3-2-1-1 elevator at 5 s, aileron doublet at 17 s, rudder doublet
    at 27 s, and from 36 s multisines on all four controls."""
    t = np.asarray(t, dtype=float)
    out = np.tile(trim_controls, (t.size, 1)).astype(float)
    dt = 0.6  # the 3-2-1-1's unit step (s)
    for start, stop, sign in ((5, 5 + 3 * dt, 1), (5 + 3 * dt, 5 + 5 * dt, -1), (5 + 5 * dt, 5 + 6 * dt, 1),
                              (5 + 6 * dt, 5 + 7 * dt, -1)):
        out[(t >= start) & (t < stop), 0] += sign * 2.0 * DEG
    out[(t >= 17) & (t < 18.5), 1] += 5.0 * DEG
    out[(t >= 18.5) & (t < 20), 1] -= 5.0 * DEG
    out[(t >= 27) & (t < 28.5), 2] += 4.0 * DEG
    out[(t >= 28.5) & (t < 30), 2] -= 4.0 * DEG
    ms = t >= 36
    tm = t[ms] - 36
    taper = np.clip(tm / 2, 0, 1) * np.clip((t[ms].max() - t[ms]) / 2 if ms.any() else 0, 0, 1)
    out[ms, 0] += taper * 1.0 * DEG * (np.sin(2 * np.pi * 0.3 * tm) + np.sin(2 * np.pi * 0.9 * tm + 1.0))
    out[ms, 1] += taper * 2.0 * DEG * (np.sin(2 * np.pi * 0.4 * tm + 2.0) + np.sin(2 * np.pi * 1.1 * tm + 0.5))
    out[ms, 2] += taper * 1.5 * DEG * (np.sin(2 * np.pi * 0.5 * tm + 1.5) + np.sin(2 * np.pi * 1.3 * tm + 2.5))
    out[ms, 3] += taper * 0.01 * (np.sin(2 * np.pi * 0.2 * tm) + np.sin(2 * np.pi * 0.7 * tm + 1.0))
    return out


#: Measurement noise std: IMU (m/s^2, rad/s), GPS position (m) and velocity (m/s), Euler
#: angles (rad), airspeed (m/s), flow angles (rad).
NOISE = {"accel": 0.02, "gyro": 0.1 * DEG, "gps_pos": 1.0, "gps_vel": 0.05, "euler": 0.1 * DEG,
         "airspeed": 0.2, "flow": 0.2 * DEG}
#: IMU biases (Eq. 6.4-6.5): accelerometers (m/s^2) and gyros (rad/s).
IMU_BIAS = np.array([0.10, -0.08, 0.12, 0.3 * DEG, -0.5 * DEG, 0.4 * DEG])
#: Constant wind in earth axes (north, east, down), m/s.
WIND = np.array([4.0, -3.0, 0.0])


@dataclass
class AircraftRecord:
    """A simulated flight and what the instruments measured (arrays of N samples).

    ``states`` (N, 12) true; ``controls`` (N, 4); ``imu`` (N, 6) measured specific force and
    rates (with bias and noise); ``gps`` (N, 6) position and ground velocity in earth axes;
    ``euler`` (N, 3); ``air`` (N, 3) V, alpha, beta; ``specific_force`` (N, 3) true.
    """

    time: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    imu: np.ndarray
    gps: np.ndarray
    euler: np.ndarray
    air: np.ndarray
    specific_force: np.ndarray
    coefficients: dict = field(default_factory=dict)
    wind: np.ndarray = field(default_factory=lambda: WIND.copy())
    imu_bias: np.ndarray = field(default_factory=lambda: IMU_BIAS.copy())


def simulate(seed: int = 0, duration: float = 60.0, rate: float = 50.0, V0: float = 50.0,
             coefficients: dict | None = None, wind=WIND, imu_bias=IMU_BIAS, noise: dict | None = None,
             airframe: Airframe = AIRFRAME) -> AircraftRecord:
    """Fly the manoeuvres from trim and measure (SciPy DOP853, rtol 1e-10, controls linear between samples)."""
    from scipy.integrate import solve_ivp

    c = dict(TRUE_COEFFICIENTS if coefficients is None else coefficients)
    noise = dict(NOISE if noise is None else noise)
    f = _functions(c, tuple(np.asarray(wind, dtype=float)), airframe)
    x0, u0 = trim(V0, c, airframe)
    t = np.arange(int(round(duration * rate)) + 1) / rate
    U = controls(t, u0)

    def rhs(tt, x):
        k = min(int(tt * rate), t.size - 2)
        frac = tt * rate - k
        return np.asarray(f(x, (1 - frac) * U[k] + frac * U[k + 1])[0]).ravel()

    sol = solve_ivp(rhs, (0.0, t[-1]), x0, method="DOP853", t_eval=t, rtol=1e-10, atol=1e-10, max_step=1 / rate)
    X = sol.y.T
    force = np.array([np.asarray(f(X[k], U[k])[1]).ravel() for k in range(t.size)])
    rng = np.random.default_rng([seed, 61])
    n = t.size
    imu = np.hstack([force, X[:, 3:6]]) + np.asarray(imu_bias) + rng.standard_normal((n, 6)) * np.repeat(
        [noise["accel"], noise["gyro"]], 3)
    V, alpha, beta = air_data(X[:, 0], X[:, 1], X[:, 2])
    phi, theta, psi = X[:, 6], X[:, 7], X[:, 8]
    ground = np.array([_dcm(phi[k], theta[k], psi[k]) @ X[k, :3] for k in range(n)]) + np.asarray(wind)
    gps = np.hstack([X[:, 9:12], ground]) + rng.standard_normal((n, 6)) * np.repeat(
        [noise["gps_pos"], noise["gps_vel"]], 3)
    euler = X[:, 6:9] + rng.standard_normal((n, 3)) * noise["euler"]
    air = np.column_stack([V, alpha, beta]) + rng.standard_normal((n, 3)) * [noise["airspeed"], noise["flow"],
                                                                                noise["flow"]]
    return AircraftRecord(t, X, U, imu, gps, euler, air, force, c, np.asarray(wind, dtype=float),
                          np.asarray(imu_bias, dtype=float))


def _dcm(phi, theta, psi) -> np.ndarray:
    """L_EB of Eq. 6.23 (body to earth)."""
    sph, cph, sth, cth, sps, cps = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta), np.sin(psi), np.cos(psi)
    return np.array([[cth * cps, sph * sth * cps - cph * sps, cph * sth * cps + sph * sps],
                     [cth * sps, sph * sth * sps + cph * cps, cph * sth * sps - sph * cps],
                     [-sth, sph * cth, cph * cth]])
