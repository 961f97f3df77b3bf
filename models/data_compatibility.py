"""Aircraft data compatibility, measurement equations (paper Appendix B.B, Eq. B6, B7, B9).

With the states x = [u v w phi theta psi] known, the measured airspeed, flow angles and
Euler angles are

    V_m     = (1 + lambda_V) sqrt(u^2 + v^2 + w^2) + b_V
    beta_m  = (1 + lambda_beta)  asin(v / V) + b_beta
    alpha_m = (1 + lambda_alpha) atan(w / u) + b_alpha
    phi_m   = (1 + lambda_phi) phi + b_phi,   theta_m, psi_m likewise

(angles in rad; psi is the continuous, unwrapped heading).

Partition. With the states known, all twelve scale factors and biases enter linearly:
the separator finds xi2 empty and stage 1 is a single linear least squares (verdict
``linear``). In the paper's Eq. B7 the IMU biases of the dynamic model (Eq. B5) form
xi2 because there the states come from integrating the biased IMU signals; once the
states are known those biases no longer appear in the measurement equations, so they
have no place in this model.

The simulator takes the air-relative velocity and attitude of the casest flight
simulator (the Pitot example's flight, 10 Hz, t = 380-700 s) as the true states.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

import casest
from casest.sim.flight import simulate_trajectory

TRUTH = {
    "lambda_V": 0.05, "b_V": -0.8,
    "lambda_beta": 0.10, "b_beta": 0.008,
    "lambda_alpha": -0.08, "b_alpha": 0.02,
    "lambda_phi": 0.02, "b_phi": -0.01,
    "lambda_theta": -0.03, "b_theta": 0.015,
    "lambda_psi": 0.01, "b_psi": 0.03,
}
#: Measurement noise std: airspeed (m/s), flow angles and Euler angles (rad).
NOISE_STD = {"V": 0.3, "beta": 0.005, "alpha": 0.005, "phi": 0.003, "theta": 0.003, "psi": 0.003}


def model() -> casest.Model:
    """Eq. B6 with the states known (Eq. B9 for V, alpha, beta)."""
    s = {n: ca.SX.sym(n) for n in list(TRUTH) + ["u", "v", "w", "phi", "theta", "psi"]}
    V = ca.sqrt(s["u"] ** 2 + s["v"] ** 2 + s["w"] ** 2)
    true = {"V": V, "beta": ca.asin(s["v"] / V), "alpha": ca.atan(s["w"] / s["u"]),
            "phi": s["phi"], "theta": s["theta"], "psi": s["psi"]}
    outputs = {f"{k}_m": (1 + s[f"lambda_{k}"]) * e + s[f"b_{k}"] for k, e in true.items()}
    P = casest.Parameter
    params = []
    for k in true:
        params.append(P(f"lambda_{k}", -0.5, 0.5, 0.0))
        params.append(P(f"b_{k}", -5.0, 5.0, 0.0, unit="m/s" if k == "V" else "rad"))
    signals = [casest.Signal(n, "m/s") for n in ("u", "v", "w")] + [casest.Signal(n, "rad") for n in ("phi", "theta", "psi")]
    return casest.Model(params, signals, outputs, name="data_compatibility")


def simulate(seed: int = 0, truth=None) -> casest.Dataset:
    """True states from the flight simulator, measured outputs with the error model and noise."""
    traj = simulate_trajectory(seed=seed, t_start=380.0, t_end=700.0, rate=10.0)
    rng = np.random.default_rng([seed, 66])
    m = model()
    signals = np.column_stack([traj.v_air_body, traj.euler])
    z = m.predict(truth or TRUTH, signals)
    z += np.array([NOISE_STD[k] for k in ("V", "beta", "alpha", "phi", "theta", "psi")]) * rng.standard_normal(z.shape)
    return casest.Dataset.from_arrays(m, signals, z)


def main(seed: int = 0) -> casest.Estimate:
    m = model()
    print(casest.separate(m).describe())
    result = casest.estimate(m, simulate(seed))
    print(result.report())
    return result


if __name__ == "__main__":
    main()
