#!/usr/bin/env python3
"""The aircraft two-step method (reference summary Sec. 6.3) on a simulated 6-DOF flight.

    python3 scripts/examples/aircraft_two_step.py [--seed 0] [--out out/aircraft] [--output-error]

Step 1: EKF + RTS smoother on the kinematic model (Eq. 6.24 states: velocities, angles,
position, IMU biases, wind) from IMU, GPS, Euler angles and air data. Step 2: the 32
coefficients of Eq. 6.25 by casest (all linear: one least squares, then ML per channel) from
the reconstructed forces and moments. Printed: the biases and wind against the truth, each
coefficient with its std (the ML std, and the std allowing for correlated residuals) against
the truth; with ``--output-error`` also output error on the full model (9 states, 38
parameters) started from the two-step estimates. Figures: reconstructed against true states,
and each coefficient equation's fit.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))

import casest  # noqa: E402
from casest.apps.sim import aircraft as ac  # noqa: E402

BIASES = ("l_x", "l_y", "l_z", "l_p", "l_q", "l_r")


def figures(out, record, smoothed, data, est, model_file):
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    os.makedirs(out, exist_ok=True)
    t = record.time
    true = np.column_stack([record.states[:, [0, 1, 2, 6, 7, 8]], np.tile(record.imu_bias, (t.size, 1)),
                            np.tile(record.wind, (t.size, 1))])
    est_x = np.column_stack([smoothed.x[:, [0, 1, 2, 3, 4, 5]], smoothed.x[:, 9:18]])
    std = np.column_stack([smoothed.std[:, [0, 1, 2, 3, 4, 5]], smoothed.std[:, 9:18]])
    names = ["u (m/s)", "v (m/s)", "w (m/s)", "phi (rad)", "theta (rad)", "psi (rad)",
             "l_x (m/s^2)", "l_y (m/s^2)", "l_z (m/s^2)", "l_p (rad/s)", "l_q (rad/s)", "l_r (rad/s)",
             "W_x (m/s)", "W_y (m/s)", "W_z (m/s)"]
    fig, axes = plt.subplots(5, 3, figsize=(13, 13), sharex=True)
    for k, ax in enumerate(axes.T.ravel()):
        ax.plot(t, true[:, k], "k", lw=1.0, label="true")
        ax.plot(t, est_x[:, k], "C1--", lw=1.0, label="smoothed")
        ax.fill_between(t, est_x[:, k] - 2 * std[:, k], est_x[:, k] + 2 * std[:, k], color="C1", alpha=0.25)
        ax.set_ylabel(names[k])
    axes[0, 0].legend(loc="best", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    fig.suptitle("Step 1: states, IMU biases and wind reconstructed by EKF + RTS smoother (band: 2 std)")
    fig.tight_layout()
    f1 = os.path.join(out, "states.png")
    fig.savefig(f1, dpi=110)
    plt.close(fig)
    pred = model_file.model().predict(est.theta, data.signals)
    fig, axes = plt.subplots(6, 1, figsize=(11, 13), sharex=True)
    for j, ax in enumerate(axes):
        ax.plot(t, data.outputs[:, j], "k", lw=0.8, label="reconstructed")
        ax.plot(t, pred[:, j], "C0", lw=1.0, label="coefficient model")
        ax.set_ylabel(model_file.COEFFICIENT_OUTPUTS[j])
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("t (s)")
    fig.suptitle("Step 2: force and moment coefficients of the reconstructed flight and their fit")
    fig.tight_layout()
    f2 = os.path.join(out, "coefficients.png")
    fig.savefig(f2, dpi=110)
    plt.close(fig)
    return [f1, f2]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=os.path.join(HERE, "..", "..", "out", "aircraft"))
    parser.add_argument("--output-error", action="store_true",
                        help="also output error on the full model from the two-step estimates (slow)")
    args = parser.parse_args(argv)
    t_start = time.perf_counter()
    mf = casest.load_model_file(os.path.join(HERE, "..", "..", "models", "aircraft.py"))
    t0 = time.perf_counter()
    record = ac.simulate(args.seed)
    t_sim = time.perf_counter() - t0
    print(f"flight: {record.time[-1]:g} s at {mf.RATE:g} Hz (N = {record.time.size}), 3-2-1-1, doublets, multisines; "
          f"simulated in {t_sim:.1f} s")

    t0 = time.perf_counter()
    _, filtered, smoothed = mf.reconstruct(record)
    t_step1 = time.perf_counter() - t0
    n = record.time.size
    truth_states = np.hstack([record.states[:, [0, 1, 2, 6, 7, 8, 9, 10, 11]], np.tile(record.imu_bias, (n, 1)),
                              np.tile(record.wind, (n, 1))])
    print(f"\nstep 1 (EKF + RTS smoother, 18 states): {t_step1:.2f} s; mean NEES of the smoothed states "
          f"{smoothed.nees(truth_states).mean():.1f} (18 for a consistent filter), of the filtered "
          f"{filtered.nees(truth_states).mean():.1f}")
    print("| augmented state | smoothed (std) | truth | (estimate - truth) / std |")
    print("|---|---|---|---|")
    names = list(BIASES) + ["W_x", "W_y", "W_z"]
    truth_aug = np.concatenate([record.imu_bias, record.wind])
    for k, name in enumerate(names):
        v, s = smoothed.x[0, 9 + k], smoothed.std[0, 9 + k]
        print(f"| {name} | {v:.5g} ({s:.2g}) | {truth_aug[k]:.5g} | {(v - truth_aug[k]) / s:+.2f} |")
    rms = np.sqrt(np.mean((smoothed.x[:, :6] - truth_states[:, :6]) ** 2, axis=0))
    print("rms error of the smoothed u, v, w (m/s), phi, theta, psi (rad): " + ", ".join(f"{v:.2g}" for v in rms))

    t0 = time.perf_counter()
    data = mf.regression_data(record, smoothed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        est = casest.estimate(mf.model(), data)
    colored = mf.colored_residual_std(est, data)
    t_step2 = time.perf_counter() - t0
    truth = mf.model().vector(mf.TRUTH)
    print(f"\nstep 2 (32 coefficients, casest: stage-1 verdict {est.landscape.verdict}, success {est.success}): "
          f"{t_step2:.2f} s")
    z_ml, z_col = (est.theta - truth) / est.std, (est.theta - truth) / colored
    oe = None
    if args.output_error:
        oe_model = mf.output_error_model()
        x0 = np.concatenate([smoothed.x[0, :3], record.imu[0, 3:] - smoothed.x[0, 12:15], smoothed.x[0, 3:6]])
        oe_data = mf.output_error_dataset(record, x0)
        start = {**dict(zip(mf.model().parameter_names, est.theta)), **dict(zip(BIASES, smoothed.x[0, 9:15]))}
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            oe = casest.estimate(oe_model, oe_data, start=start, mode="full")
        print(f"\noutput error (9 states, 38 parameters, from the two-step estimates): success {oe.success}, "
              f"{oe.n_iterations} iterations, {time.perf_counter() - t0:.1f} s")
    header = "| coefficient | truth | two-step (ML std) | z (ML std) | z (correlated-residual std) |"
    rule = "|---|---|---|---|---|"
    if oe is not None:
        header += " output error (std) | z |"
        rule += "---|---|"
    print(header)
    print(rule)
    for k, name in enumerate(mf.model().parameter_names):
        line = (f"| {name} | {truth[k]:.4g} | {est.theta[k]:.4g} ({est.std[k]:.2g}) | {z_ml[k]:+.2f} | "
                f"{z_col[k]:+.2f} |")
        if oe is not None:
            i = oe.parameter_names.index(name)
            line += f" {oe.theta[i]:.4g} ({oe.std[i]:.2g}) | {(oe.theta[i] - truth[k]) / oe.std[i]:+.2f} |"
        print(line)
    print(f"\nwithin 3 std of the truth: {np.mean(np.abs(z_ml) < 3):.0%} of the coefficients by the ML std, "
          f"{np.mean(np.abs(z_col) < 3):.0%} by the correlated-residual std (largest |z| {np.max(np.abs(z_col)):.2f})")
    files = figures(args.out, record, smoothed, data, est, mf)
    if files:
        print("figures: " + " ".join(files))
    print(f"wall time {time.perf_counter() - t_start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
