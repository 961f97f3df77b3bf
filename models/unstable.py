"""A statically unstable aircraft's short-period motion, flown with a stabilising controller.

The short-period model of ``models/short_period.py`` with a positive pitch stiffness
``M_alpha`` (the centre of gravity behind the neutral point, as in agile aircraft): the
open-loop motion diverges at about 1.1 rad/s (time to double 0.6 s). In flight a
controller closes the loop, ``delta_e = pilot + K_alpha alpha_m + K_q q_m``; the record
holds the total elevator, so the estimation model is the open-loop one driven by it::

    dalpha/dt = Z_alpha alpha + q + Z_delta delta_e
    dq/dt     = M_alpha alpha + M_q q + M_delta delta_e

Single-shooting output error integrates this open-loop model over the whole record: any
parameter error grows as ``exp(1.1 t)`` (e^13 over the 12 s record), so from the start
below (derivatives 20-50 % off) it stalls far from the optimum. Multiple shooting
(``SolverSettings(shooting="multiple")``) integrates 0.5 s intervals from state nodes tied
by continuity constraints, the nodes started from the measured outputs, so the growth
stays bounded and it reaches the optimum (``tests/test_unstable.py``). Limit: from a start
further off (M_alpha at half its value) both can stop in a local minimum with the control
derivative on its bound. The other remedy of practice, artificial stabilisation (the measured
outputs fed back into the simulation through a fixed gain), is
:func:`casest.artificially_stabilised` (``tests/test_unstable.py``).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

import casest

TRUTH = {"Z_alpha": -1.2, "Z_delta": -0.2, "M_alpha": 6.0, "M_q": -1.5, "M_delta": -15.0,
         "b_alpha": 0.005, "b_q": -0.003}
#: the flight controller (rad of elevator per rad and per rad/s of the measured states)
K_ALPHA, K_Q = 0.8, 0.25
NOISE_STD = {"alpha_m": 0.002, "q_m": 0.003}
START = {"Z_alpha": -0.8, "Z_delta": -0.1, "M_alpha": 4.0, "M_q": -1.0, "M_delta": -10.0, "b_alpha": 0.0, "b_q": 0.0}
RATE, DURATION = 50.0, 12.0


def model() -> casest.DynamicModel:
    s = {n: ca.SX.sym(n) for n in list(TRUTH) + ["alpha", "q", "delta_e"]}
    rhs = {"alpha": s["Z_alpha"] * s["alpha"] + s["q"] + s["Z_delta"] * s["delta_e"],
           "q": s["M_alpha"] * s["alpha"] + s["M_q"] * s["q"] + s["M_delta"] * s["delta_e"]}
    outputs = {"alpha_m": s["alpha"] + s["b_alpha"], "q_m": s["q"] + s["b_q"]}
    P = casest.Parameter
    params = [P("Z_alpha", -5.0, 0.0, -0.8, unit="1/s"), P("Z_delta", -1.0, 1.0, 0.0, unit="1/s"),
              P("M_alpha", -5.0, 15.0, 3.0, unit="1/s^2"), P("M_q", -10.0, 0.0, -1.0, unit="1/s"),
              P("M_delta", -40.0, -1.0, -10.0, unit="1/s^2"), P("b_alpha", -0.1, 0.1, 0.0, unit="rad"),
              P("b_q", -0.05, 0.05, 0.0, unit="rad/s")]
    states = [casest.State("alpha", 0.0, "rad"), casest.State("q", 0.0, "rad/s")]
    return casest.DynamicModel(params, states, [casest.Signal("delta_e", "rad")], rhs, outputs, name="unstable",
                               output_units={"alpha_m": "rad", "q_m": "rad/s"}, input_hold="zoh")


def pilot(t: np.ndarray) -> np.ndarray:
    """3-2-1-1 (unit 0.5 s, 1.5 deg) from 1 s and a doublet (1 deg, 1 s) from 7 s."""
    deg = np.pi / 180
    u = np.zeros_like(t)
    edges = np.cumsum([1.0, 1.5, 1.0, 0.5, 0.5])
    for a, b, sign in zip(edges[:-1], edges[1:], [1, -1, 1, -1]):
        u[(t >= a) & (t < b)] = 1.5 * deg * sign
    u[(t >= 7.0) & (t < 8.0)], u[(t >= 8.0) & (t < 9.0)] = deg, -deg
    return u


def simulate(seed: int = 0, truth=None) -> casest.Dataset:
    """The closed-loop flight: the controller acts on the noisy measurements, held over each sample
    (the record's elevator is what it commanded); the states by the exact discretisation."""
    from scipy.linalg import expm

    c = dict(TRUTH if truth is None else truth)
    A = np.array([[c["Z_alpha"], 1.0], [c["M_alpha"], c["M_q"]]])
    B = np.array([c["Z_delta"], c["M_delta"]])
    dt = 1.0 / RATE
    aug = np.zeros((3, 3))
    aug[:2, :2], aug[:2, 2] = A, B
    E = expm(aug * dt)
    Phi, Gamma = E[:2, :2], E[:2, 2]
    rng = np.random.default_rng([seed, 311])
    t = np.arange(int(DURATION * RATE) + 1) / RATE
    x, Z, U = np.zeros(2), [], []
    bias = np.array([c["b_alpha"], c["b_q"]])
    std = np.array([NOISE_STD["alpha_m"], NOISE_STD["q_m"]])
    for k in range(t.size):
        z = x + bias + std * rng.standard_normal(2)
        u = pilot(t[k:k + 1])[0] + K_ALPHA * (z[0] - bias[0]) + K_Q * (z[1] - bias[1])  # trimmed sensors
        Z.append(z)
        U.append(u)
        x = Phi @ x + Gamma * u
    Z = np.array(Z)
    return model().dataset({"t": t, "delta_e": np.array(U), "alpha_m": Z[:, 0], "q_m": Z[:, 1]})


def main(seed: int = 0) -> casest.Estimate:
    settings = casest.SolverSettings(shooting="multiple", shooting_interval=25)
    est = casest.estimate(model(), simulate(seed), start=START, mode="full", solver_settings=settings)
    print(est.report())
    return est


if __name__ == "__main__":
    main()
