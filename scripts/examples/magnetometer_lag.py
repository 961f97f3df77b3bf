#!/usr/bin/env python3
"""The bundled magnetometer model on a record in time whose sensor lags its attitude reference.

    python3 scripts/examples/magnetometer_lag.py [--lag-ms 15] [--rate 100] [--seconds 20] [--seed 0]

A tumbling motion (roll and pitch oscillating, yaw turning; rates up to about 1 rad/s) sampled
at ``--rate`` Hz; the magnetometer reads the field of ``--lag-ms`` milliseconds earlier (its
filter's delay), with the bundled model's truth and noise (0.2 uT per axis). The model knows
nothing of the lag. The script prints what casest concludes, the diagnosis, and the refit with
the diagnosed delay; with ``--lag-ms 0`` the same record without a lag.
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import numpy as np  # noqa: E402

import casest  # noqa: E402


def attitude(t: np.ndarray) -> np.ndarray:
    """(phi, theta, psi) of the tumbling motion at times t (s), rad."""
    return np.column_stack([0.9 * np.sin(2 * np.pi * 0.23 * t), 0.6 * np.sin(2 * np.pi * 0.17 * t + 1.0),
                            0.8 * t + 0.5 * np.sin(2 * np.pi * 0.11 * t)])


def lagged_record(lag_s: float, rate: float, seconds: float, seed: int) -> casest.Dataset:
    """The record: the reference attitude at t, the sensor's reading of the field at t - lag."""
    mag = casest.load_model_file("magnetometer")
    model = mag.model()
    t = np.arange(0.0, seconds, 1.0 / rate)
    rng = np.random.default_rng([seed, 15])
    z = model.predict(mag.TRUTH, attitude(t - lag_s)) + mag.NOISE_STD * rng.standard_normal((t.size, 3))
    data = casest.Dataset.from_arrays(model, attitude(t), z)
    data.time_ordered = True
    return data


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lag-ms", type=float, default=15.0)
    parser.add_argument("--rate", type=float, default=100.0, help="samples per second")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    model = casest.load_model_file("magnetometer").model()
    data = lagged_record(args.lag_ms / 1000.0, args.rate, args.seconds, args.seed)
    est = casest.estimate(model, data)
    code, reason = est.conclusion()
    print(f"lag {args.lag_ms:g} ms = {args.lag_ms * args.rate / 1000.0:g} samples at {args.rate:g} Hz, "
          f"N = {data.n_samples}")
    print(f"conclusion: {code.value}: {reason}")
    rms = np.sqrt(np.mean((data.outputs - model.predict(est.theta, data.signals)) ** 2, axis=0))
    print("residual rms per axis (uT):", np.round(rms, 3))
    if est.diagnosis is not None:
        refit = casest.refit(est, model, data)
        print(refit.describe())
        d = refit.value
        print(f"delay {d:.3f} +/- {refit.std:.3f} samples = {1000 * d / args.rate:.2f} +/- "
              f"{1000 * refit.std / args.rate:.2f} ms (truth {args.lag_ms:g} ms)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
