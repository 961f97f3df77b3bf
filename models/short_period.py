"""Longitudinal short-period dynamics of an aircraft (a dynamic example, summary Sec. 6).

The linearised short-period motion about trim, states x = [alpha, q] (angle of attack and
pitch rate, perturbations from trim, zero at t = 0), input u = delta_e (elevator, rad)::

    dalpha/dt = Z_alpha alpha + q + Z_delta delta_e
    dq/dt     = M_alpha alpha + M_q q + M_delta delta_e

with dimensional derivatives Z (1/s) and M (1/s^2, 1/s). Measured: the vane angle of
attack with a bias, the pitch rate with a gyro bias, and the normal acceleration
``a_z = V0 (Z_alpha alpha + Z_delta delta_e)`` (m/s^2)::

    alpha_m = alpha + b_alpha,   q_m = q + b_q,   a_z_m = V0 (Z_alpha alpha + Z_delta delta_e)

The separator puts the five stability and control derivatives in xi2 (they drive the
states) and the two sensor biases in xi1. The simulator flies a 3-2-1-1 elevator input
and a doublet (20 s at 50 Hz) and adds white measurement noise.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

import casest

V0 = 25.0  # trim airspeed, m/s
TRUTH = {"Z_alpha": -1.8, "Z_delta": -0.25, "M_alpha": -12.0, "M_q": -3.2, "M_delta": -18.0,
         "b_alpha": 0.01, "b_q": -0.004}
NOISE_STD = {"alpha_m": 0.002, "q_m": 0.003, "a_z_m": 0.15}
SINGLE_STAGE_START = {"Z_alpha": -1.0, "Z_delta": 0.0, "M_alpha": -5.0, "M_q": -1.0, "M_delta": -5.0,
                      "b_alpha": 0.0, "b_q": 0.0}
RATE, DURATION = 50.0, 20.0


def model(substeps: int = 1) -> casest.DynamicModel:
    s = {n: ca.SX.sym(n) for n in list(TRUTH) + ["alpha", "q", "delta_e"]}
    rhs = {
        "alpha": s["Z_alpha"] * s["alpha"] + s["q"] + s["Z_delta"] * s["delta_e"],
        "q": s["M_alpha"] * s["alpha"] + s["M_q"] * s["q"] + s["M_delta"] * s["delta_e"],
    }
    outputs = {
        "alpha_m": s["alpha"] + s["b_alpha"],
        "q_m": s["q"] + s["b_q"],
        "a_z_m": V0 * (s["Z_alpha"] * s["alpha"] + s["Z_delta"] * s["delta_e"]),
    }
    P = casest.Parameter
    params = [
        P("Z_alpha", -5.0, -0.2, -1.0, unit="1/s"),
        P("Z_delta", -1.0, 0.5, 0.0, unit="1/s"),
        P("M_alpha", -40.0, -1.0, -5.0, unit="1/s^2"),
        P("M_q", -10.0, -0.2, -1.0, unit="1/s"),
        P("M_delta", -50.0, -1.0, -5.0, unit="1/s^2"),
        P("b_alpha", -0.1, 0.1, 0.0, unit="rad"),
        P("b_q", -0.05, 0.05, 0.0, unit="rad/s"),
    ]
    states = [casest.State("alpha", 0.0, "rad"), casest.State("q", 0.0, "rad/s")]
    return casest.DynamicModel(params, states, [casest.Signal("delta_e", "rad")], rhs, outputs, name="short_period",
                               output_units={"alpha_m": "rad", "q_m": "rad/s", "a_z_m": "m/s^2"}, substeps=substeps)


def elevator(t: np.ndarray) -> np.ndarray:
    """A 3-2-1-1 input (unit 0.5 s, from t = 1 s) and a doublet (from t = 10 s), 2 deg, smoothed edges."""
    def pulse(t0, width, sign):
        return sign * (0.5 + 0.5 * np.tanh((t - t0) / 0.03)) * (0.5 - 0.5 * np.tanh((t - t0 - width) / 0.03))

    unit = 0.5
    u = pulse(1.0, 3 * unit, 1) + pulse(1.0 + 3 * unit, 2 * unit, -1) + pulse(1.0 + 5 * unit, unit, 1) \
        + pulse(1.0 + 6 * unit, unit, -1)
    u += pulse(10.0, 1.0, 1) + pulse(11.0, 1.0, -1)
    return np.deg2rad(2.0) * u


def simulate(seed: int = 0, truth=None) -> casest.Dataset:
    """The 3-2-1-1 and doublet record with noise (fixed seed), exact states from RK4 with 8 substeps."""
    truth = dict(TRUTH if truth is None else truth)
    t = np.arange(int(DURATION * RATE) + 1) / RATE
    u = elevator(t)
    fine, exact = model(), model(substeps=8)
    zeros = np.zeros_like(t)
    _, clean = exact.simulate(truth, exact.dataset({"t": t, "delta_e": u, **{n: zeros for n in fine.output_names}}))
    rng = np.random.default_rng([seed, 71])
    z = clean + rng.standard_normal(clean.shape) * np.array([NOISE_STD[n] for n in fine.output_names])
    return fine.dataset({"t": t, "delta_e": u, **{n: z[:, j] for j, n in enumerate(fine.output_names)}})


def simulate_random(seed: int = 0, duration: float = 400.0, truth=None) -> casest.Dataset:
    """A long record under a random binary elevator input (+-2 deg, each level held 0.5-2 s), noise
    as :func:`simulate`: a stationary excitation, for online estimation (recursive ML)."""
    truth = dict(TRUTH if truth is None else truth)
    t = np.arange(int(duration * RATE) + 1) / RATE
    rng = np.random.default_rng([seed, 72])
    switches = np.cumsum(rng.uniform(0.5, 2.0, size=int(duration) + 1))
    u = np.deg2rad(2.0) * np.where(np.searchsorted(switches, t) % 2 == 0, 1.0, -1.0)
    fine, exact = model(), model(substeps=8)
    zeros = np.zeros_like(t)
    _, clean = exact.simulate(truth, exact.dataset({"t": t, "delta_e": u, **{n: zeros for n in fine.output_names}}))
    z = clean + rng.standard_normal(clean.shape) * np.array([NOISE_STD[n] for n in fine.output_names])
    return fine.dataset({"t": t, "delta_e": u, **{n: z[:, j] for j, n in enumerate(fine.output_names)}})


def main(seed: int = 0) -> casest.Estimate:
    m = model()
    print(casest.separate(m).describe())
    est = casest.estimate(m, simulate(seed))
    print(est.report())
    return est


if __name__ == "__main__":
    main()
