"""5-hole Pitot-tube calibration (paper Sec. IV, Eq. 35-42) on a simulated UAV flight.

States x = [p q r b_gx b_gy b_gz phi theta psi] (navigation solution), inputs
u = [P_alpha P_beta P_t P_s] (probe pressures), outputs z = V_NED (navigation solution),
parameters xi = [lambda_V b_V lambda_alpha b_alpha lambda_beta b_beta eps_a W_N W_E W_D].

Air-data error model (Eq. 36), with q_c = P_t - P_s::

    V_a   = (1 + lambda_V) sqrt(2 q_c / rho) + b_V
    alpha = (1 + lambda_alpha) P_alpha / (K_alpha q_c) + b_alpha      [deg]
    beta  = (1 + lambda_beta)  P_beta  / (K_beta  q_c) + b_beta       [deg]

Wind triangle with lever arm and misalignment (Eq. 37-41)::

    V_NED = C_b^n [ C(eps_a) V_a (cos a cos b, sin b, sin a cos b) - (omega x r) ] + W

with omega = (p - b_gx, q - b_gy, r - b_gz) and the probe at r (body axes) from the IMU.
The separator finds xi1 = [lambda_V b_V W_N W_E W_D] and xi2 = [lambda_alpha b_alpha
lambda_beta b_beta eps_a] (Eq. 42) by itself.

Constants: rho = 1.2 kg/m^3, K_alpha = K_beta = 0.08 / deg, r = (0.35, 0.75, -0.05) m.
The simulator inverts the same equations, so a noise-free flight is reproduced exactly.

Run ``python models/pitot5hole.py`` for one simulated flight, or
``scripts/paper/pitot_calibration.py`` for the paper's tables and figures.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

import casest
from casest.apps.sim.flight import DEG, MANEUVERS, dcm_body_to_ned_symbolic, simulate_trajectory, static_pressure

RHO = 1.2  # kg/m^3, air density assumed by the error model
K_ALPHA = 0.08  # 1/deg
K_BETA = 0.08  # 1/deg
LEVER_ARM = (0.35, 0.75, -0.05)  # m, IMU to probe, body axes

#: A true parameter set near the paper's Table 6 estimates.
TRUTH = {
    "lambda_V": -0.17,
    "b_V": 4.4,
    "lambda_alpha": 0.30,
    "b_alpha": -2.5,
    "lambda_beta": -0.27,
    "b_beta": -1.3,
    "eps_a": -0.14,
    "W_N": -3.8,
    "W_E": 2.4,
    "W_D": -0.7,
}

#: Navigation-solution noise on V_NED (m/s), the size of the paper's Table 7.
NAV_NOISE_STD = (0.99, 0.86, 0.92)
PRESSURE_NOISE_STD = 1.0  # Pa, each probe port
GYRO_NOISE_STD = 0.002  # rad/s
GYRO_BIAS = (0.012, -0.021, 0.006)  # rad/s, known to the navigation filter
REFERENCE_PITOT_STD = 0.1  # m/s, the independently calibrated Pitot tube

#: Stage-1 sweep of the paper: 500 random xi2 from N(0, 2^2) and eps_a from N(0, 0.3491^2).
SWEEP_SETTINGS = casest.SweepSettings(design="random", n_candidates=500)

#: The single-stage comparison starts every parameter at zero (Sec. IV).
SINGLE_STAGE_START = {name: 0.0 for name in TRUTH}

SIGNALS = [
    ("p", "rad/s"), ("q", "rad/s"), ("r", "rad/s"),
    ("b_gx", "rad/s"), ("b_gy", "rad/s"), ("b_gz", "rad/s"),
    ("phi", "rad"), ("theta", "rad"), ("psi", "rad"),
    ("P_alpha", "Pa"), ("P_beta", "Pa"), ("P_t", "Pa"), ("P_s", "Pa"),
]
UNITS = dict(SIGNALS, V_N="m/s", V_E="m/s", V_D="m/s", time="s", V_ref="m/s")


def _c_eps(eps):
    return ca.vertcat(
        ca.horzcat(1, 0, 0),
        ca.horzcat(0, ca.cos(eps), ca.sin(eps)),
        ca.horzcat(0, -ca.sin(eps), ca.cos(eps)),
    )


def air_data(sym: dict):
    """Eq. 36: calibrated airspeed (m/s), alpha and beta (rad) from the probe pressures."""
    qc = sym["P_t"] - sym["P_s"]
    va = (1 + sym["lambda_V"]) * ca.sqrt(2 * qc / RHO) + sym["b_V"]
    alpha = ((1 + sym["lambda_alpha"]) * sym["P_alpha"] / (K_ALPHA * qc) + sym["b_alpha"]) * DEG
    beta = ((1 + sym["lambda_beta"]) * sym["P_beta"] / (K_BETA * qc) + sym["b_beta"]) * DEG
    return va, alpha, beta


def model() -> casest.Model:
    """The wind-triangle measurement model of Eq. 37-41 with Table 6's constraints."""
    names = [n for n, _ in SIGNALS] + list(TRUTH)
    sym = {n: ca.SX.sym(n) for n in names}
    va, alpha, beta = air_data(sym)
    direction = ca.vertcat(ca.cos(alpha) * ca.cos(beta), ca.sin(beta), ca.sin(alpha) * ca.cos(beta))
    C_bn = dcm_body_to_ned_symbolic(sym["phi"], sym["theta"], sym["psi"])
    omega = ca.vertcat(sym["p"] - sym["b_gx"], sym["q"] - sym["b_gy"], sym["r"] - sym["b_gz"])
    lever = ca.cross(omega, ca.DM(LEVER_ARM))
    wind = ca.vertcat(sym["W_N"], sym["W_E"], sym["W_D"])
    v_ned = ca.mtimes(C_bn, ca.mtimes(_c_eps(sym["eps_a"]), direction) * va - lever) + wind
    wide = casest.Gaussian(0.0, 2.0)
    P = casest.Parameter
    parameters = [
        P("lambda_V", -0.5, 0.5, 0.0),
        P("b_V", -5.0, 5.0, 0.0, unit="m/s"),
        P("lambda_alpha", -0.5, 0.5, 0.0, prior=wide),
        P("b_alpha", -5.0, 5.0, 0.0, prior=wide, unit="deg"),
        P("lambda_beta", -0.5, 0.5, 0.0, prior=wide),
        P("b_beta", -5.0, 5.0, 0.0, prior=wide, unit="deg"),
        P("eps_a", -0.2618, 0.2618, 0.0, prior=casest.Gaussian(0.0, 0.3491), unit="rad"),
        P("W_N", -6.0, 6.0, 0.0, unit="m/s"),
        P("W_E", -6.0, 6.0, 0.0, unit="m/s"),
        P("W_D", -2.0, 2.0, 0.0, unit="m/s"),
    ]
    return casest.Model(
        parameters=parameters,
        signals=[casest.Signal(n, u) for n, u in SIGNALS],
        outputs={"V_N": v_ned[0], "V_E": v_ned[1], "V_D": v_ned[2]},
        name="pitot5hole",
        output_units={"V_N": "m/s", "V_E": "m/s", "V_D": "m/s"},
    )


def probe_pressures(traj, truth=None):
    """Invert Eq. 36 at the probe: pressures that the true error model maps to the true air data.

    Returns
    -------
    dict of ndarray (N,): P_alpha, P_beta, P_t, P_s (Pa) and V_probe (m/s, true airspeed at the probe)
    """
    th = dict(TRUTH if truth is None else truth)
    omega = traj.body_rates
    v_probe_body = traj.v_air_body + np.cross(omega, np.asarray(LEVER_ARM))
    ce, se = np.cos(th["eps_a"]), np.sin(th["eps_a"])
    C_eps = np.array([[1, 0, 0], [0, ce, se], [0, -se, ce]])
    v_probe = v_probe_body @ C_eps  # C(eps)^T v, row-wise: probe axes
    speed = np.linalg.norm(v_probe, axis=1)
    alpha_deg = np.degrees(np.arctan2(v_probe[:, 2], v_probe[:, 0]))
    beta_deg = np.degrees(np.arcsin(v_probe[:, 1] / speed))
    qc = 0.5 * RHO * ((speed - th["b_V"]) / (1 + th["lambda_V"])) ** 2
    p_alpha = (alpha_deg - th["b_alpha"]) * K_ALPHA * qc / (1 + th["lambda_alpha"])
    p_beta = (beta_deg - th["b_beta"]) * K_BETA * qc / (1 + th["lambda_beta"])
    p_s = static_pressure(traj.altitude)
    return {"P_alpha": p_alpha, "P_beta": p_beta, "P_t": p_s + qc, "P_s": p_s, "V_probe": speed}


def simulate(seed: int = 0, noise: bool = True, truth=None, t_end: float = 1140.0, circle_banks=None,
             t_start: float = 360.0) -> casest.Dataset:
    """One calibration flight at 50 Hz (t = ``t_start``, default 360 s, to ``t_end``) with known truth.

    Parameters
    ----------
    seed : int
        Seeds the noise and small variations of the manoeuvres.
    noise : bool
        False gives exact signals (the model then reproduces V_NED to round-off).
    truth : mapping, optional
        Parameter values; default :data:`TRUTH`.
    t_end : float
        End of the record (s); longer records repeat gentle turns after the manoeuvres.
    circle_banks : tuple of two float, optional
        Bank angles (deg) of the two wind circles (default: the seed's, about 27 and -25).

    Returns
    -------
    Dataset
        Signals and outputs of the model, plus extra columns ``time`` (s) and ``V_ref``
        (m/s, airspeed from an independently calibrated Pitot tube beside the probe).
    """
    th = dict(TRUTH if truth is None else truth)
    traj = simulate_trajectory(wind_ned=(th["W_N"], th["W_E"], th["W_D"]), seed=seed, t_start=t_start, t_end=t_end,
                               circle_banks=circle_banks)
    rng = np.random.default_rng([seed, 35])
    n = traj.time.size
    press = probe_pressures(traj, th)
    scale = 1.0 if noise else 0.0
    bias = np.asarray(GYRO_BIAS)
    gyro = traj.body_rates + bias + scale * GYRO_NOISE_STD * rng.standard_normal((n, 3))
    columns = {
        "p": gyro[:, 0], "q": gyro[:, 1], "r": gyro[:, 2],
        "b_gx": np.full(n, bias[0]), "b_gy": np.full(n, bias[1]), "b_gz": np.full(n, bias[2]),
        "phi": traj.euler[:, 0], "theta": traj.euler[:, 1], "psi": traj.euler[:, 2],
    }
    for key in ("P_alpha", "P_beta", "P_t", "P_s"):
        columns[key] = press[key] + scale * PRESSURE_NOISE_STD * rng.standard_normal(n)
    v_meas = traj.v_ned + scale * np.asarray(NAV_NOISE_STD) * rng.standard_normal((n, 3))
    columns.update({"V_N": v_meas[:, 0], "V_E": v_meas[:, 1], "V_D": v_meas[:, 2]})
    columns["time"] = traj.time
    columns["V_ref"] = press["V_probe"] + scale * REFERENCE_PITOT_STD * rng.standard_normal(n)
    return casest.Dataset(model(), columns, extra=["time", "V_ref"])


def windows(stage: int) -> list:
    """Table 5's time windows (s) used by stage 1 or stage 2."""
    return [(t0, t1) for _, t0, t1, s in MANEUVERS if s == stage]


def stage_data(data: casest.Dataset) -> tuple:
    """Split a flight into the stage-1 and stage-2 data of Table 5."""
    t = data.column("time")
    out = []
    for stage in (1, 2):
        mask = np.zeros(t.size, dtype=bool)
        for t0, t1 in windows(stage):
            mask |= (t >= t0) & (t <= t1)
        out.append(data.subset(mask))
    return tuple(out)


def calibrated_airspeed(data: casest.Dataset, theta) -> np.ndarray:
    """Airspeed at the probe (m/s) from Eq. 36 with the given parameters, shape (N,)."""
    th = dict(zip(model().parameter_names, model().vector(theta)))
    qc = data.column("P_t") - data.column("P_s")
    return (1 + th["lambda_V"]) * np.sqrt(2 * qc / RHO) + th["b_V"]


def main(seed: int = 0) -> casest.Estimate:
    """Simulate one flight, estimate with Table 5's windows, print the report."""
    data = simulate(seed)
    stage1, stage2 = stage_data(data)
    result = casest.estimate(model(), stage2, stage1_data=stage1, sweep_settings=SWEEP_SETTINGS)
    print(result.report())
    return result


if __name__ == "__main__":
    main()
