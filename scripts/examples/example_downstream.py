#!/usr/bin/env python3
"""Embedding example 2: use the calibrated model downstream, in the same CasADi problem.

    python3 scripts/examples/example_downstream.py

A sensor follows scalar example 1, z = (1 + a) cos(eta + b) + c. We calibrate it from a
data record and, in the same Opti problem, choose the input eta in [1, 3] rad at which
the calibrated sensor reads a target value z* = 0.5. The estimator enters as a
casadi.Function (data in, estimates out), and the data record is an Opti parameter: the
problem is built once and re-solved for a second record without rebuilding.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402

import casest  # noqa: E402
from casest.interop import estimator_function  # noqa: E402

TARGET = 0.5


def main() -> list:
    module = casest.load_model_file("scalar1")
    model = module.model()
    records = [module.simulate(seed) for seed in (0, 1)]
    N = records[0].n_samples
    estimator = estimator_function(model, N)

    opti = ca.Opti()
    signals = opti.parameter(1, N)
    outputs = opti.parameter(1, N)
    eta = opti.variable()
    theta, _ = estimator(signals, outputs, ca.DM([0.5, 0.1, 0.5]))  # calibration inside the graph
    reading = model.function(eta, theta)
    opti.minimize((reading - TARGET) ** 2)
    opti.subject_to(opti.bounded(1.0, eta, 3.0))
    opti.set_initial(eta, 2.0)
    opti.solver("ipopt", {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"})

    answers = []
    for seed, data in zip((0, 1), records):
        opti.set_value(signals, data.signals.T)
        opti.set_value(outputs, data.outputs.T)
        sol = opti.solve()
        th = np.asarray(sol.value(theta)).ravel()
        eta_star = float(sol.value(eta))
        truth_eta = float(np.arccos((TARGET - module.TRUTH["c"]) / (1 + module.TRUTH["a"])) - module.TRUTH["b"])
        print(f"record {seed}: calibrated a, b, c = {np.round(th, 4).tolist()}; input for z* = {TARGET}: "
              f"eta = {eta_star:.4f} rad (with the true parameters: {truth_eta:.4f}); "
              f"calibrated reading there {float(sol.value(reading)):.6f}")
        answers.append(eta_star)
    return answers


if __name__ == "__main__":
    main()
