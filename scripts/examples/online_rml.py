#!/usr/bin/env python3
"""Recursive maximum likelihood online (summary Sec. 5.3): theta and R sample by sample.

    python3 scripts/examples/online_rml.py [--samples 5000] [--seed 3]
    python3 scripts/examples/online_rml.py --dynamic [--duration 400] [--seed 0]

The samples of a simulated record (paper Eq. 33, noise std 0.3) arrive in a random order, as a
stationary excitation would deliver them; RecursiveML starts near the truth with a nearly flat
prior and takes one Newton step per sample (Eq. 5.8, 5.10-5.13). Printed: the estimate every
tenth of the record against the batch ML estimate of the whole record, in batch std.

``--dynamic``: the short-period aircraft model (a DynamicModel) under a random binary elevator
input, in time order, by the output-error predictor with its state sensitivities, starting 10 %
off in every parameter, with the forgetting schedule lambda(0) = 0.9, r = 0.995; the batch
estimate is casest's output error of the whole record.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402
from casest.recursive.ml import RecursiveML  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=5000, help="samples in the record")
    parser.add_argument("--seed", type=int, default=3, help="seed of the simulated noise")
    parser.add_argument("--dynamic", action="store_true", help="the short-period DynamicModel instead of scalar 2")
    parser.add_argument("--duration", type=float, default=400.0, help="record length with --dynamic (s, 50 Hz)")
    args = parser.parse_args(argv)
    if args.dynamic:
        return _dynamic(args.seed, args.duration)
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


def _dynamic(seed: int, duration: float) -> int:
    module = casest.load_model_file("short_period")
    model, data = module.model(), module.simulate_random(seed, duration)
    batch = casest.estimate(model, data)
    R0 = 4.0 * np.array([module.NOISE_STD[n] for n in model.output_names]) ** 2
    rml = RecursiveML(model, {k: 1.1 * v for k, v in module.TRUTH.items()}, R0, forgetting=0.9,
                      forgetting_rate=0.995)
    rml.predictor.start(data, rml.theta)
    names = model.parameter_names
    print("samples | " + " | ".join(f"{n} (batch std)" for n in names))
    for part in np.array_split(np.arange(data.n_samples), 10):  # in time order, one sample per step
        for k in part:
            rml.update(data.signals[[k]], data.outputs[[k]])
        z = (rml.theta - batch.theta) / batch.std
        print(f"{rml.n_samples:7d} | " + " | ".join(f"{t:.5g} ({d:+.2f})" for t, d in zip(rml.theta, z)))
    print("batch   | " + " | ".join(f"{t:.5g}" for t in batch.theta))
    print("R / batch R: " + ", ".join(f"{r:.4f}" for r in rml.R / batch.R)
          + "; std / batch std: " + ", ".join(f"{r:.3f}" for r in rml.std / batch.std))
    return 0


if __name__ == "__main__":
    sys.exit(main())
