#!/usr/bin/env python3
"""Recursive maximum likelihood online (summary Sec. 5.3): theta and R of scalar 2 sample by sample.

    python3 scripts/online_rml.py [--samples 5000] [--seed 3]

The samples of a simulated record (paper Eq. 33, noise std 0.3) arrive in a random order, as a
stationary excitation would deliver them; RecursiveML starts near the truth with a nearly flat
prior and takes one Newton step per sample (Eq. 5.8, 5.10-5.13). Printed: the estimate every
tenth of the record against the batch ML estimate of the whole record, in batch std.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import casest  # noqa: E402
from casest.state.recursive_ml import RecursiveML  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=5000, help="samples in the record")
    parser.add_argument("--seed", type=int, default=3, help="seed of the simulated noise")
    args = parser.parse_args(argv)
    module = casest.load_model_file("scalar2")
    model = module.model()
    data = module.simulate(args.seed, n=args.samples)
    batch = casest.estimate(model, data)
    order = np.random.default_rng(0).permutation(data.n_samples)
    rml = RecursiveML(model, model.vector(module.TRUTH) + np.array([0.1, 0.02, 0.05, -0.1]), [0.5])
    names = model.parameter_names
    print("samples | " + " | ".join(f"{n} (batch std)" for n in names) + " | R")
    for part in np.array_split(order, 10):
        for k in part:  # one sample at a time, as online
            rml.update(data.signals[[k]], data.outputs[[k]])
        z = (rml.theta - batch.theta) / batch.std
        print(f"{rml.n_samples:7d} | " + " | ".join(f"{t:.5f} ({d:+.2f})" for t, d in zip(rml.theta, z))
              + f" | {rml.R[0]:.5f}")
    print("batch   | " + " | ".join(f"{t:.5f}" for t in batch.theta) + f" | {batch.R[0]:.5f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
