"""The aircraft two-step method (reference summary Sec. 6.3) on a simulated 6-DOF flight.

Step 1 reconstructs the states from the instruments alone (no aerodynamic model): the
kinematic model of Eq. 6.16-6.23 driven by the measured specific forces and rates, with the
IMU biases and the wind as augmented states (Eq. 6.24)::

    du/dt = (A_xm - l_x) - (q_m - l_q) w + (r_m - l_r) v - g sin(theta)      (v, w likewise)
    dphi/dt, dtheta/dt, dpsi/dt: Eq. 6.20-6.22 with the rates q_m - l_q, ...
    d[x y z]/dt = L_EB [u v w] + W,   dl/dt = 0,   dW/dt = 0

measured through GPS position and ground velocity, the Euler angles and the air data
(V, alpha, beta of [u v w]). ``kinematic_model()`` declares it; ``reconstruct(record)``
runs the EKF and the RTS smoother over a record (the IMU's noise as input noise, which
the filter maps into the states through the kinematics). Step 2 (``model()``, ``regression_data``) fits the 32 coefficients
of Eq. 6.25 to the force and moment coefficients of the reconstructed flight: the specific
forces corrected by the estimated biases give C_X, C_Y, C_Z (Eq. 6.14), the bias-corrected
rates and their derivative (Savitzky-Golay) give the moments of Eq. 6.19 and C_l, C_m, C_n.
Every coefficient enters linearly: stage 1 is one linear least squares and stage 2 the ML
estimate with each channel's noise.

``output_error_model()`` is the full model for output error: the rigid-body states
u ... psi of Eq. 6.16-6.22 driven by the controls, measured as V, alpha, beta, the rates and
specific forces (each with its IMU bias) and the Euler angles; the 32 coefficients and the
six IMU biases are its parameters.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

import casest
from casest.apps.sim import aircraft as ac

G = ac.G
KINEMATIC_STATES = ("u", "v", "w", "phi", "theta", "psi", "x", "y", "z",
                    "l_x", "l_y", "l_z", "l_p", "l_q", "l_r", "W_x", "W_y", "W_z")
IMU = ("A_xm", "A_ym", "A_zm", "p_m", "q_m", "r_m")
KINEMATIC_OUTPUTS = ("x_gps", "y_gps", "z_gps", "vn_gps", "ve_gps", "vd_gps", "phi_m", "theta_m", "psi_m",
                     "V_m", "alpha_m", "beta_m")
COEFFICIENT_OUTPUTS = ("CX_m", "CY_m", "CZ_m", "Cl_m", "Cm_m", "Cn_m")
REGRESSORS = ("alpha", "beta", "V", "p", "q", "r", "de", "da", "dr", "Tc")
TRUTH = dict(ac.TRUE_COEFFICIENTS)
RATE = 50.0


def _dcm(phi, theta, psi):
    sph, cph, sth, cth, sps, cps = ca.sin(phi), ca.cos(phi), ca.sin(theta), ca.cos(theta), ca.sin(psi), ca.cos(psi)
    return ca.vertcat(ca.horzcat(cth * cps, sph * sth * cps - cph * sps, cph * sth * cps + sph * sps),
                      ca.horzcat(cth * sps, sph * sth * sps + cph * cps, cph * sth * sps - sph * cps),
                      ca.horzcat(-sth, sph * cth, cph * cth))


def kinematic_model() -> casest.DynamicModel:
    """Step 1: Eq. 6.16-6.23 with the IMU as inputs, biases and wind as states (Eq. 6.24)."""
    s = {n: ca.SX.sym(n) for n in KINEMATIC_STATES + IMU}
    u, v, w, phi, theta = s["u"], s["v"], s["w"], s["phi"], s["theta"]
    ax, ay, az = s["A_xm"] - s["l_x"], s["A_ym"] - s["l_y"], s["A_zm"] - s["l_z"]
    p, q, r = s["p_m"] - s["l_p"], s["q_m"] - s["l_q"], s["r_m"] - s["l_r"]
    L_EB = _dcm(phi, theta, s["psi"])
    ground = L_EB @ ca.vertcat(u, v, w) + ca.vertcat(s["W_x"], s["W_y"], s["W_z"])
    rhs = {
        "u": ax - q * w + r * v - G * ca.sin(theta),
        "v": ay - r * u + p * w + G * ca.cos(theta) * ca.sin(phi),
        "w": az - p * v + q * u + G * ca.cos(theta) * ca.cos(phi),
        "phi": p + (q * ca.sin(phi) + r * ca.cos(phi)) * ca.tan(theta),
        "theta": q * ca.cos(phi) - r * ca.sin(phi),
        "psi": (q * ca.sin(phi) + r * ca.cos(phi)) / ca.cos(theta),
        "x": ground[0], "y": ground[1], "z": ground[2],
        **{n: ca.SX(0) for n in KINEMATIC_STATES[9:]},
    }
    V = ca.sqrt(u**2 + v**2 + w**2)
    outputs = {"x_gps": s["x"], "y_gps": s["y"], "z_gps": s["z"], "vn_gps": ground[0], "ve_gps": ground[1],
               "vd_gps": ground[2], "phi_m": phi, "theta_m": theta, "psi_m": s["psi"],
               "V_m": V, "alpha_m": ca.atan2(w, u), "beta_m": ca.asin(v / V)}
    states = [casest.State(n, 0.0) for n in KINEMATIC_STATES]
    return casest.DynamicModel([], states, list(IMU), rhs, outputs, name="aircraft_kinematics", input_hold="linear")


def measurement_noise(noise: dict | None = None) -> np.ndarray:
    """Variances of the kinematic model's outputs (12,)."""
    n = dict(ac.NOISE if noise is None else noise)
    std = [n["gps_pos"]] * 3 + [n["gps_vel"]] * 3 + [n["euler"]] * 3 + [n["airspeed"], n["flow"], n["flow"]]
    return np.asarray(std) ** 2


def kinematic_dataset(record: ac.AircraftRecord) -> casest.Dataset:
    """The step-1 record: time, IMU, GPS, Euler angles and air data."""
    cols = {"t": record.time}
    cols.update({n: record.imu[:, k] for k, n in enumerate(IMU)})
    meas = np.hstack([record.gps, record.euler, record.air])
    cols.update({n: meas[:, k] for k, n in enumerate(KINEMATIC_OUTPUTS)})
    return kinematic_model().dataset(cols)


def reconstruct(record: ac.AircraftRecord, noise: dict | None = None):
    """Step 1: EKF and RTS smoother over the record; returns (model, filter result, smoothed)."""
    from casest.filters import ExtendedKalmanFilter, rts_smoother

    n = dict(ac.NOISE if noise is None else noise)
    model = kinematic_model()
    data = kinematic_dataset(record)
    dt = 1.0 / RATE
    # the IMU's white noise, sampled at the record's rate, is input noise of intensity std^2 dt:
    # the filter maps it into the states through the kinematics (gyro noise times the airspeed
    # on the velocity rates); biases and wind may drift very slowly
    q_acc, q_gyro = n["accel"] ** 2 * dt, n["gyro"] ** 2 * dt
    imu_noise = {k: (q_acc if k.startswith("A") else q_gyro) for k in IMU}
    process = {k: 1e-10 for k in KINEMATIC_STATES[9:]}
    V, alpha, beta = record.air[0]
    u0 = V * np.array([np.cos(alpha) * np.cos(beta), np.sin(beta), np.sin(alpha) * np.cos(beta)])
    x0 = np.concatenate([u0, record.euler[0], record.gps[0, :3], np.zeros(9)])
    P0 = np.diag(np.concatenate([[1.0] * 3, [(1 * ac.DEG) ** 2] * 3, [n["gps_pos"] ** 2] * 3,
                                 [0.3**2] * 3, [(1 * ac.DEG) ** 2] * 3, [5.0**2] * 3]))
    ekf = ExtendedKalmanFilter(model, [], process, measurement_noise(n), P0, x0=x0, input_noise=imu_noise)
    result = ekf.filter(data)
    return model, result, rts_smoother(result)


def model() -> casest.Model:
    """Step 2: the six coefficient equations (Eq. 6.8-6.13) with the 32 coefficients of Eq. 6.25.

    The force equations take the reconstructed flight as it is; the moment equations take it
    through the same smoothing filter as the angular accelerations (signals ``*_f``).
    """
    s = {n: ca.SX.sym(n) for n in REGRESSORS + tuple(f"{r}_f" for r in REGRESSORS) + ac.COEFFICIENTS}
    c = {k: s[k] for k in ac.COEFFICIENTS}
    raw = ac.coefficient_expressions(*[s[r] for r in REGRESSORS], c)
    filtered = ac.coefficient_expressions(*[s[f"{r}_f"] for r in REGRESSORS], c)
    params = [casest.Parameter(k, -50.0, 50.0, 0.0) for k in ac.COEFFICIENTS]
    units = {"alpha": "rad", "beta": "rad", "V": "m/s", "p": "rad/s", "q": "rad/s", "r": "rad/s", "de": "rad",
             "da": "rad", "dr": "rad", "Tc": ""}
    signals = [casest.Signal(r, units[r]) for r in REGRESSORS] + [casest.Signal(f"{r}_f", units[r]) for r in REGRESSORS]
    outputs = {"CX_m": raw["CX"], "CY_m": raw["CY"], "CZ_m": raw["CZ"],
               "Cl_m": filtered["Cl"], "Cm_m": filtered["Cm"], "Cn_m": filtered["Cn"]}
    return casest.Model(params, signals, outputs, name="aircraft_coefficients")


def regression_data(record: ac.AircraftRecord, smoothed, window: int = 11) -> casest.Dataset:
    """Step 2's data from the reconstructed flight: regressors and measured coefficients.

    Forces: the specific forces corrected by the smoothed IMU biases give C_X, C_Y, C_Z against
    the reconstructed states. Moments (Eq. 6.19): ``I omega_dot + omega x I omega`` with the
    bias-corrected rates and their derivative by a Savitzky-Golay filter (cubic, ``window``
    samples); their regressors pass through the same filter (a filter on both sides of the
    regression biases no coefficient, while the derivative filter alone would attenuate the
    fast manoeuvres' moments by several per cent).
    """
    from scipy.signal import savgol_filter

    af = ac.AIRFRAME
    x = smoothed.x
    V, alpha, beta = ac.air_data(x[:, 0], x[:, 1], x[:, 2])
    bias = x[:, 9:15]
    force = record.imu[:, :3] - bias[:, :3]
    omega = record.imu[:, 3:] - bias[:, 3:]
    dt = record.time[1] - record.time[0]
    omega_dot = savgol_filter(omega, window, 3, deriv=1, delta=dt, axis=0)
    raw = np.column_stack([alpha, beta, V, omega, record.controls])
    filtered = savgol_filter(raw, window, 3, axis=0)
    omega_f = filtered[:, 3:6]
    I = af.inertia
    moments = omega_dot @ I.T + np.cross(omega_f, omega_f @ I.T)
    qS = 0.5 * af.rho * V**2 * af.S
    qS_f = 0.5 * af.rho * filtered[:, 2] ** 2 * af.S
    C = np.column_stack([af.mass * force / qS[:, None], moments / (qS_f[:, None] * np.array([af.b, af.cbar, af.b]))])
    return casest.Dataset.from_arrays(model(), np.hstack([raw, filtered]), C)


def colored_residual_std(est: casest.Estimate, data: casest.Dataset, max_lag: int = 40) -> np.ndarray:
    """Standard deviations that allow for correlated residuals (per channel), shape (n_parameters,).

    The ML std assume white residuals; the smoothed moment equations (and any modelling error)
    make them correlated in time. Each coefficient belongs to one channel, so per channel the
    least-squares covariance is the sandwich ``(J'J)^-1 J' C J (J'J)^-1`` with C the Toeplitz
    matrix of the residuals' autocovariance up to ``max_lag`` samples (beyond it: zero).
    """
    from casest.backend.sums import prediction_and_jacobian

    m = model()
    h, J = prediction_and_jacobian(m, data.signals, est.theta)
    ny, N = m.n_outputs, data.n_samples
    h, J = h.reshape(N, ny), J.reshape(N, ny, -1)
    std = np.full(m.n_parameters, np.nan)
    for j in range(ny):
        cols = np.flatnonzero(np.any(J[:, j, :] != 0, axis=0))
        Jj = J[:, j, cols]
        e = data.outputs[:, j] - h[:, j]
        acov = np.array([e[: N - k] @ e[k:] / N for k in range(max_lag + 1)])
        # J' C J with C Toeplitz of acov, without forming C
        M = acov[0] * Jj.T @ Jj
        for k in range(1, max_lag + 1):
            cross = Jj[:-k].T @ Jj[k:]
            M += acov[k] * (cross + cross.T)
        inv = np.linalg.inv(Jj.T @ Jj)
        std[cols] = np.sqrt(np.diag(inv @ M @ inv))
    return std


def output_error_model() -> casest.DynamicModel:
    """The full model for output error: Eq. 6.8-6.22 driven by the controls, 32 coefficients and 6 IMU biases."""
    names = ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi")
    s = {n: ca.SX.sym(n) for n in names + ac.CONTROLS + ac.COEFFICIENTS + ("l_x", "l_y", "l_z", "l_p", "l_q", "l_r")}
    x = ca.vertcat(*[s[n] for n in names], ca.SX.zeros(3))
    rhs, force = ac.rigid_body(x, ca.vertcat(*[s[n] for n in ac.CONTROLS]), {k: s[k] for k in ac.COEFFICIENTS})
    V, alpha, beta = ac.air_data(s["u"], s["v"], s["w"])
    outputs = {"V_m": V, "alpha_m": alpha, "beta_m": beta,
               "p_m": s["p"] + s["l_p"], "q_m": s["q"] + s["l_q"], "r_m": s["r"] + s["l_r"],
               "phi_m": s["phi"], "theta_m": s["theta"], "psi_m": s["psi"],
               "A_xm": force[0] + s["l_x"], "A_ym": force[1] + s["l_y"], "A_zm": force[2] + s["l_z"]}
    params = [casest.Parameter(k, -50.0, 50.0, 0.0) for k in ac.COEFFICIENTS]
    params += [casest.Parameter(k, -1.0, 1.0, 0.0) for k in ("l_x", "l_y", "l_z")]
    params += [casest.Parameter(k, -0.1, 0.1, 0.0) for k in ("l_p", "l_q", "l_r")]
    states = [casest.State(n, "data") for n in names]
    return casest.DynamicModel(params, states, list(ac.CONTROLS), {n: rhs[i] for i, n in enumerate(names)}, outputs,
                               name="aircraft_output_error")


def output_error_dataset(record: ac.AircraftRecord, initial_state: np.ndarray) -> casest.Dataset:
    """Controls, measured outputs and the initial state (9,) (from step 1's smoother)."""
    cols = {"t": record.time}
    cols.update({n: record.controls[:, k] for k, n in enumerate(ac.CONTROLS)})
    cols.update({"V_m": record.air[:, 0], "alpha_m": record.air[:, 1], "beta_m": record.air[:, 2],
                 "p_m": record.imu[:, 3], "q_m": record.imu[:, 4], "r_m": record.imu[:, 5],
                 "phi_m": record.euler[:, 0], "theta_m": record.euler[:, 1], "psi_m": record.euler[:, 2],
                 "A_xm": record.imu[:, 0], "A_ym": record.imu[:, 1], "A_zm": record.imu[:, 2]})
    for k, n in enumerate(("u", "v", "w", "p", "q", "r", "phi", "theta", "psi")):
        cols[n] = np.full(record.time.size, initial_state[k])
    return output_error_model().dataset(cols)


def simulate(seed: int = 0) -> casest.Dataset:
    """A flight and its step 1: the step-2 regression data (the model file's default record)."""
    record = ac.simulate(seed)
    _, _, smoothed = reconstruct(record)
    return regression_data(record, smoothed)


def main(seed: int = 0) -> casest.Estimate:
    est = casest.estimate(model(), simulate(seed))
    print(est.report())
    return est


if __name__ == "__main__":
    main()
