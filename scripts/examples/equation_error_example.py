#!/usr/bin/env python3
"""Equation error and stepwise model-structure selection, on simulated data and on the bundled
AP2 flight record (docs/howto/equation-error.md).

    python3 scripts/examples/equation_error_example.py

1. A pitching-moment coefficient simulated from Cm0 + Cm_alpha alpha + Cm_q q_hat + Cm_de de
   with white noise (seed 7): stepwise regression among nine candidates, the selected structure
   and its estimates against the truth.
2. The AP2 record (data/ampyx_ap2): the pitch acceleration from the measured pitch rate by a
   Savitzky-Golay derivative (window 21 samples = 0.42 s, cubic), regressed on terms scaled by
   the dynamic pressure n = (V / 25 m/s)^2, the pitch rate and the tether tension; stepwise
   selection among thirteen candidates.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402

import casest  # noqa: E402
from casest.data import savitzky_golay  # noqa: E402

AP2_PATHS = {"t": "validationData.controls.times", "da": "validationData.controls.aileron",
             "de": "validationData.controls.elevator", "dr": "validationData.controls.rudder",
             "V": "validationData.response.airspeed", "alpha": "validationData.response.angleOfAttack",
             "beta": "validationData.response.sideSlip", "T": "validationData.response.tetherTension",
             "p": "validationData.response.w[0]", "q": "validationData.response.w[1]", "r": "validationData.response.w[2]"}


def simulated() -> None:
    rng = np.random.default_rng(7)
    n = 1500
    t = np.arange(n) * 0.02
    data = {"alpha": 0.08 * np.sin(0.7 * t) + 0.03 * np.sin(2.9 * t + 1),
            "q": 0.2 * np.cos(1.1 * t) + 0.05 * rng.standard_normal(n),
            "de": 0.05 * np.sign(np.sin(0.45 * t + 0.3)) + 0.01 * rng.standard_normal(n),
            "V": 24.0 + 2.0 * np.sin(0.1 * t)}
    truth = {"bias": 0.02, "alpha": -0.9, "q_hat": -15.0, "de": -1.2}
    q_hat = data["q"] * 0.5 / (2 * data["V"])
    cm = truth["bias"] + truth["alpha"] * data["alpha"] + truth["q_hat"] * q_hat + truth["de"] * data["de"]
    cm = cm + 0.002 * rng.standard_normal(n)
    alpha, q, de, V = (ca.SX.sym(k) for k in ("alpha", "q", "de", "V"))
    candidates = {"bias": 1, "alpha": alpha, "q_hat": q * 0.5 / (2 * V), "de": de, "alpha2": alpha**2,
                  "alpha_de": alpha * de, "alpha_q": alpha * q * 0.5 / (2 * V), "de2": de**2, "V": V}
    result = casest.stepwise(cm, candidates, data, always=["bias"])
    print("=== 1. Simulated pitching moment (truth: bias, alpha, q_hat, de) ===")
    print(result.report())
    print("truth:", truth)


def ap2() -> None:
    cols = casest.read_mat_paths(casest.bundled_data_dir("ampyx_ap2", "validationDataFC114_1_v2_pc.mat"), AP2_PATHS)
    cols = {k: np.asarray(v, dtype=float).reshape(-1) for k, v in cols.items()}
    dt = float(np.mean(np.diff(cols["t"])))
    q_dot = savitzky_golay(cols["q"], dt, window=21, order=3, derivative=1)
    s = {k: ca.SX.sym(k) for k in cols}
    n = (s["V"] / 25.0) ** 2
    linear = {"bias": 1, "n": n, "n_alpha": n * s["alpha"], "n_de": n * s["de"], "q": s["q"], "T": s["T"]}
    print("\n=== 2. AP2 pitch acceleration, the output-error model's terms ===")
    print(casest.regress(q_dot, linear, cols).table())
    candidates = {**linear, "n_beta": n * s["beta"], "n_da": n * s["da"], "n_dr": n * s["dr"], "p": s["p"],
                  "r": s["r"], "n_alpha2": n * s["alpha"] ** 2, "n_alpha_de": n * s["alpha"] * s["de"]}
    print("\n=== 3. AP2 pitch acceleration, stepwise among 13 candidates ===")
    print(casest.stepwise(q_dot, candidates, cols, always=["bias"]).report())


if __name__ == "__main__":
    simulated()
    ap2()
