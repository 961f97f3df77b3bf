#!/usr/bin/env python3
"""The paper's Tables 2 and 4 against the Cramer-Rao bound at the paper's own estimates.

    python3 scripts/paper/paper_std_reading.py

For each scalar example: the paper's estimates and R (Tables 2 and 4) in the paper's setting
(N = 100 samples, eta evenly spaced on [1, 10], the model files' ``simulate`` grid), the
Fisher information J'J / R with J the exact Jacobian of the model at those estimates, and the
ratio of the paper's reported std to the square root of the inverse's diagonal. Also where the
paper's "true R" (the variance of its 100 noise samples) lies in the distribution of a
100-sample variance of N(0, 0.3^2) noise: sd 0.09 sqrt(2 / 99).
"""

from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402
from casest.problem.measurement import measurement_of  # noqa: E402

PAPER = {  # Tables 2 and 4: estimates, estimated R, reported std, the "true R"
    "scalar1": ({"a": 0.9512, "b": 0.0812, "c": 0.9415}, 0.1199, {"a": 0.0507, "b": 0.0182, "c": 0.0360}, 0.1237),
    "scalar2": ({"a": 0.9980, "b": 0.0546, "c": 0.0895, "d": 0.9897}, 0.1008,
                {"a": 0.0474, "b": 0.0059, "c": 0.0351, "d": 0.0333}, 0.1016),
}
SIGMA2 = 0.3**2


def main() -> int:
    for name, (estimates, R, reported, true_R) in PAPER.items():
        module = casest.load_model_file(name)
        model, data = module.model(), module.simulate(0)
        _, J = measurement_of(model).prediction_and_jacobian(model.vector(estimates), data)
        bound = np.sqrt(np.diag(np.linalg.inv(J.T @ J / R)))
        part = casest.separate(model)
        print(f"{name} (N = {data.n_samples}; linear {list(part.linear)}, nonlinear {list(part.nonlinear)}):")
        for n, b in zip(model.parameter_names, bound):
            print(f"  {n}: paper std {reported[n]:.4f}, Cramer-Rao at the paper's estimates {b:.4f}, "
                  f"ratio {reported[n] / b:.3f}")
        spread = SIGMA2 * np.sqrt(2.0 / 99.0)
        print(f"  the paper's true R {true_R}: {(true_R - SIGMA2) / spread:+.1f} sd of a 100-sample variance "
              f"from sigma^2 = {SIGMA2:.2f} (sd {spread:.4f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
