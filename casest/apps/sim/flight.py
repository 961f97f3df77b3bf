"""A small fixed-wing UAV calibration flight with the manoeuvres of paper Table 5.

The trajectory is one rigid body: Euler angles, air-relative velocity (V_a, alpha, beta)
and the turn rate are smooth functions of time; the body rates follow from the exact
Euler-angle kinematics, the inertial velocity from the wind triangle
``V_NED = C_b^n V_air + W``, and the altitude from integrating V_D. Turns are coordinated
(``psi_dot = g tan(phi) / V_a``).

Manoeuvres and their windows (seconds, Table 5)::

    wind circle 1   [384, 408.2]      stage 1
    wind circle 2   [411, 438.3]      stage 1
    pushover-pullup [510.9, 530]      stage 1
    multisine 1-4   [576, 596], [690, 711], [752, 772], [810, 830]   stage 2
    pitch chirp 1   [867, 887]        stage 2
    yaw chirp       [980.080, 1013.595]  stage 2
    pitch chirp 2   [1041, 1061]      stage 2
    rudder doublet  [1113, 1115]      stage 2
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


__all__ = [
    "MANEUVERS",
    "FlightTrajectory",
    "simulate_trajectory",
    "euler_rates_to_body",
    "dcm_body_to_ned",
    "dcm_body_to_ned_symbolic",
]

G = 9.80665
DEG = np.pi / 180.0

#: (name, t_start, t_end, stage) of paper Table 5.
MANEUVERS = (
    ("wind circle 1", 384.0, 408.2, 1),
    ("wind circle 2", 411.0, 438.3, 1),
    ("pushover-pullup", 510.9, 530.0, 1),
    ("multisine 1", 576.0, 596.0, 2),
    ("multisine 2", 690.0, 711.0, 2),
    ("multisine 3", 752.0, 772.0, 2),
    ("multisine 4", 810.0, 830.0, 2),
    ("pitch chirp 1", 867.0, 887.0, 2),
    ("yaw chirp", 980.080, 1013.595, 2),
    ("pitch chirp 2", 1041.0, 1061.0, 2),
    ("rudder doublet", 1113.0, 1115.0, 2),
)

#: Gentle heading changes between manoeuvres: (t_start, t_end, bank in degrees).
_CRUISE_TURNS = (
    (445.0, 480.0, 15.0),
    (540.0, 565.0, -18.0),
    (605.0, 680.0, 10.0),
    (720.0, 745.0, -15.0),
    (838.0, 860.0, 18.0),
    (895.0, 970.0, -10.0),
    (1020.0, 1035.0, 15.0),
    (1068.0, 1105.0, -12.0),
)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    """C2-continuous step from 0 (x <= 0) to 1 (x >= 1)."""
    x = np.clip(x, 0.0, 1.0)
    return x**3 * (10 - 15 * x + 6 * x**2)


def _plateau(t: np.ndarray, t0: float, t1: float, ramp: float) -> np.ndarray:
    """1 on [t0, t1], smooth ramps of length ``ramp`` outside it, 0 far away."""
    return _smoothstep((t - (t0 - ramp)) / ramp) * (1.0 - _smoothstep((t - t1) / ramp))


def _taper(t: np.ndarray, t0: float, t1: float, ramp: float) -> np.ndarray:
    """1 inside [t0 + ramp, t1 - ramp], smooth ramps to 0 at t0 and t1."""
    return _smoothstep((t - t0) / ramp) * (1.0 - _smoothstep((t - (t1 - ramp)) / ramp))


def _multisine(t: np.ndarray, t0: float, freqs, phase_offset: float) -> np.ndarray:
    """Sum of sines with Schroeder phases, unit peak amplitude (about)."""
    k = np.arange(1, len(freqs) + 1)
    phases = -np.pi * k * (k - 1) / len(freqs) + phase_offset
    out = sum(np.sin(2 * np.pi * f * (t - t0) + ph) for f, ph in zip(freqs, phases))
    return out / np.sqrt(len(freqs) * 2.0)


def _chirp(t: np.ndarray, t0: float, t1: float, f0: float = 0.1, f1: float = 1.2) -> np.ndarray:
    tau = t - t0
    return np.sin(2 * np.pi * (f0 * tau + 0.5 * (f1 - f0) * tau**2 / (t1 - t0)))


class _Profile:
    """The commanded flight: V_a, alpha, beta, phi and flight-path angle as functions of time."""

    def __init__(self, rng: np.random.Generator, wind_down: float = 0.0, circle_banks=None):
        # small flight-to-flight variation of the manoeuvres, so seeds differ in more than noise
        self.v_cruise = 17.0 + rng.uniform(-1.0, 1.0)
        self.circle_bank = (27.0 + rng.uniform(-2, 2)) * DEG, (-25.0 + rng.uniform(-2, 2)) * DEG
        if circle_banks is not None:  # the design's candidates: wind circles at chosen banks
            self.circle_bank = tuple(float(b) * DEG for b in circle_banks)
        self.ms_phase = rng.uniform(0, 2 * np.pi, size=3)
        # sink through the air mass at the rate of the updraft, so the altitude stays level
        self.gamma_trim = float(np.arcsin(np.clip(wind_down / self.v_cruise, -0.2, 0.2)))

    def airspeed(self, t):
        v = self.v_cruise + 2.0 * np.sin(2 * np.pi * t / 170.0)
        v += 2.0 * _plateau(t, 411.0, 438.3, 3.0)  # faster second circle
        popu = _taper(t, 510.9, 530.0, 1.5)
        v += 2.5 * popu * np.cos(2 * np.pi * (t - 510.9) / 9.55)  # speed trades with the climb
        return v

    def gamma(self, t):
        popu = _taper(t, 510.9, 530.0, 1.5)
        return self.gamma_trim + 9.0 * DEG * popu * np.sin(2 * np.pi * (t - 510.9) / 9.55)

    def alpha(self, t):
        v = self.airspeed(t)
        a = 4.0 * DEG * (17.0 / v) ** 2  # trim: lift ~ V^2 alpha
        a += 3.0 * DEG * _taper(t, 510.9, 530.0, 1.5) * np.sin(2 * np.pi * (t - 510.9) / 9.55 + 0.6)
        for name, t0, t1, _ in MANEUVERS:
            if name.startswith("multisine"):
                a += 2.0 * DEG * _taper(t, t0, t1, 1.0) * _multisine(t, t0, (0.25, 0.55, 0.95, 1.35), self.ms_phase[1])
            elif name.startswith("pitch chirp"):
                a += 3.0 * DEG * _taper(t, t0, t1, 1.0) * _chirp(t, t0, t1)
        return a

    def beta(self, t):
        b = np.zeros_like(t)
        for name, t0, t1, _ in MANEUVERS:
            if name.startswith("multisine"):
                b += 3.0 * DEG * _taper(t, t0, t1, 1.0) * _multisine(t, t0, (0.3, 0.65, 1.05, 1.45), self.ms_phase[2])
            elif name == "yaw chirp":
                b += 5.0 * DEG * _taper(t, t0, t1, 1.5) * _chirp(t, t0, t1, 0.1, 1.0)
            elif name == "rudder doublet":
                b += 6.0 * DEG * (_taper(t, t0, t0 + 1.0, 0.15) - _taper(t, t0 + 1.0, t1, 0.15))
        return b

    def bank(self, t):
        phi = self.circle_bank[0] * _plateau(t, 384.0, 408.2, 2.5)
        phi += self.circle_bank[1] * _plateau(t, 411.0, 438.3, 2.5)
        for t0, t1, bank in _CRUISE_TURNS:
            phi += bank * DEG * _plateau(t, t0, t1, 3.0)
        for name, t0, t1, _ in MANEUVERS:
            if name.startswith("multisine"):
                phi += 8.0 * DEG * _taper(t, t0, t1, 1.0) * _multisine(t, t0, (0.2, 0.45, 0.85, 1.25), self.ms_phase[0])
        return phi

    def pitch(self, t):
        # flight-path angle plus angle of attack projected through the bank
        return self.gamma(t) + self.alpha(t) * np.cos(self.bank(t))


def dcm_body_to_ned(phi, theta, psi) -> np.ndarray:
    """C_b^n (paper Eq. 39) for arrays of angles, shape (..., 3, 3)."""
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    return np.stack(
        [
            np.stack([ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp], -1),
            np.stack([ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp], -1),
            np.stack([-st, sf * ct, cf * ct], -1),
        ],
        -2,
    )


def dcm_body_to_ned_symbolic(phi, theta, psi):
    """C_b^n (paper Eq. 39) as a 3 x 3 CasADi expression of the Euler angles (3-2-1)."""
    import casadi as ca

    cf, sf, ct, st, cp, sp = ca.cos(phi), ca.sin(phi), ca.cos(theta), ca.sin(theta), ca.cos(psi), ca.sin(psi)
    return ca.vertcat(
        ca.horzcat(ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp),
        ca.horzcat(ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp),
        ca.horzcat(-st, sf * ct, cf * ct),
    )


def euler_rates_to_body(phi, theta, phi_dot, theta_dot, psi_dot) -> np.ndarray:
    """Body rates [p, q, r] from Euler angles and their rates (3-2-1), shape (..., 3)."""
    p = phi_dot - psi_dot * np.sin(theta)
    q = theta_dot * np.cos(phi) + psi_dot * np.sin(phi) * np.cos(theta)
    r = -theta_dot * np.sin(phi) + psi_dot * np.cos(phi) * np.cos(theta)
    return np.stack([p, q, r], -1)


@dataclass
class FlightTrajectory:
    """True kinematics of the flight, sampled at ``rate`` Hz.

    Attributes
    ----------
    time : ndarray, shape (N,), s
    euler : ndarray, shape (N, 3), rad (phi, theta, psi)
    body_rates : ndarray, shape (N, 3), rad/s (p, q, r)
    airspeed : ndarray, shape (N,), m/s (at the centre of the IMU)
    alpha, beta : ndarray, shape (N,), rad
    v_air_body : ndarray, shape (N, 3), m/s (air-relative velocity at the IMU, body axes)
    v_ned : ndarray, shape (N, 3), m/s (inertial velocity)
    wind_ned : ndarray, shape (3,), m/s
    altitude : ndarray, shape (N,), m
    specific_force : ndarray, shape (N, 3), m/s^2
        What an ideal IMU at the centre of gravity measures (body axes):
        ``d V_air / dt + omega x V_air - C_n^b g``. With the steady wind this is also the
        specific force of the inertial motion, so the kinematics of paper Eq. B5 hold for the
        air-relative velocity.
    """

    time: np.ndarray
    euler: np.ndarray
    body_rates: np.ndarray
    airspeed: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray
    v_air_body: np.ndarray
    v_ned: np.ndarray
    wind_ned: np.ndarray
    altitude: np.ndarray
    specific_force: np.ndarray | None = None


def simulate_trajectory(
    wind_ned=(-3.8, 2.4, -0.7),
    t_start: float = 360.0,
    t_end: float = 1140.0,
    rate: float = 50.0,
    seed: int = 0,
    altitude0: float = 300.0,
    heading0: float | None = None,
    circle_banks: tuple | None = None,
) -> FlightTrajectory:
    """Generate the calibration flight.

    Parameters
    ----------
    wind_ned : array_like, shape (3,), m/s
        Steady wind (north, east, down).
    t_start, t_end : float, s
        Span of the flight (Table 5's manoeuvres lie in [384, 1115]).
    rate : float, Hz
    seed : int
        Varies the cruise speed, the circle bank angles, the multisine phases and the
        initial heading.
    circle_banks : tuple of two float, optional
        Bank angles (deg) of the two wind circles, instead of the seed's (about 27 and -25).
    """
    rng = np.random.default_rng([seed, 7])
    prof = _Profile(rng, wind_down=float(np.asarray(wind_ned, dtype=float)[2]), circle_banks=circle_banks)
    n = int(round((t_end - t_start) * rate)) + 1
    t = t_start + np.arange(n) / rate
    h = 1e-4  # central differences of the smooth profiles: error ~ h^2 * f'''
    phi, theta = prof.bank(t), prof.pitch(t)
    phi_dot = (prof.bank(t + h) - prof.bank(t - h)) / (2 * h)
    theta_dot = (prof.pitch(t + h) - prof.pitch(t - h)) / (2 * h)
    va, alpha, beta = prof.airspeed(t), prof.alpha(t), prof.beta(t)
    psi_dot = G * np.tan(phi) / va
    # heading: integrate the turn rate on a 10x finer grid (Simpson), then sample
    fine = t_start + np.arange(10 * (n - 1) + 1) / (10 * rate)
    psi_dot_fine = G * np.tan(prof.bank(fine)) / prof.airspeed(fine)
    dt = 1.0 / (10 * rate)
    increments = (psi_dot_fine[:-2:2] + 4 * psi_dot_fine[1:-1:2] + psi_dot_fine[2::2]) * dt / 3
    psi_even = np.concatenate([[0.0], np.cumsum(increments)])  # at fine[0::2]
    psi0 = rng.uniform(-np.pi, np.pi) if heading0 is None else heading0
    psi = psi0 + psi_even[::5]
    euler = np.column_stack([phi, theta, psi])
    rates = euler_rates_to_body(phi, theta, phi_dot, theta_dot, psi_dot)
    def air_velocity(tt):
        v, a, b = prof.airspeed(tt), prof.alpha(tt), prof.beta(tt)
        return v[:, None] * np.column_stack([np.cos(a) * np.cos(b), np.sin(b), np.sin(a) * np.cos(b)])

    v_air = air_velocity(t)
    C = dcm_body_to_ned(phi, theta, psi)
    v_air_dot = (air_velocity(t + h) - air_velocity(t - h)) / (2 * h)
    gravity_body = np.einsum("nji,j->ni", C, np.array([0.0, 0.0, G]))  # C' g
    specific_force = v_air_dot + np.cross(rates, v_air) - gravity_body
    wind = np.asarray(wind_ned, dtype=float)
    v_ned = np.einsum("nij,nj->ni", C, v_air) + wind
    altitude = altitude0 - np.concatenate([[0.0], np.cumsum(0.5 * (v_ned[1:, 2] + v_ned[:-1, 2]) / rate)])
    return FlightTrajectory(t, euler, rates, va, alpha, beta, v_air, v_ned, wind, altitude, specific_force)


def static_pressure(altitude: np.ndarray) -> np.ndarray:
    """International Standard Atmosphere static pressure (Pa) below 11 km."""
    return 101325.0 * (1.0 - 2.25577e-5 * np.asarray(altitude)) ** 5.25588
