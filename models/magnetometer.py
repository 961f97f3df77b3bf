"""Three-axis magnetometer calibration (paper Appendix B.A, Eq. B1-B3).

    h_m = C_si C_eta C_lambda h_b + n + v

with the soft-iron matrix C_si = I + [[0, a_xy, a_xz], [a_xy, 0, a_yz], [a_xz, a_yz, 0]]
(symmetric), the small-angle misalignment C_eta = I + [eta]_x (skew), the scale factors
C_lambda = diag(1 + lambda) and the hard-iron bias n. The true body-axis field is
h_b = C_b^n(phi, theta, psi)^T h_ref with a known reference field h_ref (NED, about
50 uT); the attitude is known. Twelve parameters; 3 + 3 + 3 entries of the three matrices
are the 9 degrees of freedom of a general matrix, so all are identifiable when the
attitudes cover the sphere.

Partition. The bias n enters linearly, and so does each matrix on its own: h is affine in
lambda (for fixed alpha, eta), in alpha (for fixed eta, lambda) and in eta (for fixed alpha,
lambda), but any two of the three multiply each other. The separator therefore finds
three equally large jointly affine sets, {lambda, n}, {alpha, n} and {eta, n} (six
parameters each), and reports the tie (``Partition.alternatives``). With the parameters
declared as below it takes the first, xi1 = [lambda, n], xi2 = [alpha, eta]: the paper's
split of Eq. B3. (Had the soft-iron matrix been a full 3 x 3 matrix, {alpha, n} would be
strictly larger and would win, but the model would no longer be identifiable.)

Run ``python models/magnetometer.py`` to simulate and estimate one data set.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from scipy.spatial.transform import Rotation

import casest
from casest.apps.sim.flight import dcm_body_to_ned_symbolic

H_REF = (22.0, 1.5, 44.0)  # uT, reference field in NED (|h| = 49.2 uT)
NOISE_STD = 0.2  # uT per axis

TRUTH = {
    "lambda_x": 0.04, "lambda_y": -0.03, "lambda_z": 0.02,
    "n_x": 5.0, "n_y": -3.0, "n_z": 8.0,
    "alpha_xy": 0.015, "alpha_xz": -0.01, "alpha_yz": 0.02,
    "eta_x": 0.01, "eta_y": -0.015, "eta_z": 0.005,
}


def model() -> casest.Model:
    """Eq. B1 with symmetric soft iron, skew misalignment and diagonal scale factors."""
    s = {n: ca.SX.sym(n) for n in list(TRUTH) + ["phi", "theta", "psi"]}
    C_si = ca.vertcat(
        ca.horzcat(1, s["alpha_xy"], s["alpha_xz"]),
        ca.horzcat(s["alpha_xy"], 1, s["alpha_yz"]),
        ca.horzcat(s["alpha_xz"], s["alpha_yz"], 1),
    )
    C_eta = ca.vertcat(
        ca.horzcat(1, -s["eta_z"], s["eta_y"]),
        ca.horzcat(s["eta_z"], 1, -s["eta_x"]),
        ca.horzcat(-s["eta_y"], s["eta_x"], 1),
    )
    C_lam = ca.diag(ca.vertcat(1 + s["lambda_x"], 1 + s["lambda_y"], 1 + s["lambda_z"]))
    h_b = ca.mtimes(dcm_body_to_ned_symbolic(s["phi"], s["theta"], s["psi"]).T, ca.DM(H_REF))
    h_m = ca.mtimes(C_si, ca.mtimes(C_eta, ca.mtimes(C_lam, h_b))) + ca.vertcat(s["n_x"], s["n_y"], s["n_z"])
    P = casest.Parameter
    small = casest.Gaussian(0.0, 0.03)
    params = [P(f"lambda_{a}", -0.3, 0.3, 0.0) for a in "xyz"]
    params += [P(f"n_{a}", -20.0, 20.0, 0.0, unit="uT") for a in "xyz"]
    params += [P(n, -0.1, 0.1, 0.0, prior=small) for n in ("alpha_xy", "alpha_xz", "alpha_yz")]
    params += [P(f"eta_{a}", -0.1, 0.1, 0.0, prior=small, unit="rad") for a in "xyz"]
    return casest.Model(
        params,
        [casest.Signal("phi", "rad"), casest.Signal("theta", "rad"), casest.Signal("psi", "rad")],
        {"m_x": h_m[0], "m_y": h_m[1], "m_z": h_m[2]},
        name="magnetometer",
    )


def simulate(seed: int = 0, n: int = 600, noise_std: float = NOISE_STD, truth=None) -> casest.Dataset:
    """``n`` attitudes drawn uniformly over all rotations, the calibrated sensor's readings.

    Parameters
    ----------
    seed : int
    n : int
        Samples.
    noise_std : float
        Sensor noise per axis (uT).
    truth : mapping, optional
        Default :data:`TRUTH`.
    """
    rng = np.random.default_rng([seed, 21])
    euler = Rotation.random(n, random_state=rng).as_euler("ZYX")  # psi, theta, phi (3-2-1)
    psi, theta, phi = euler[:, 0], euler[:, 1], euler[:, 2]
    m = model()
    signals = np.column_stack([phi, theta, psi])
    z = m.predict(truth or TRUTH, signals) + noise_std * rng.standard_normal((n, 3))
    return casest.Dataset.from_arrays(m, signals, z)


def main(seed: int = 0) -> casest.Estimate:
    m = model()
    print(casest.separate(m).describe())
    result = casest.estimate(m, simulate(seed))
    print(result.report())
    return result


if __name__ == "__main__":
    main()
