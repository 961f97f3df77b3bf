#!/usr/bin/env python3
"""Aircraft data compatibility with the kinematics integrated (paper Appendix B.B, Eq. B4-B8).

    python3 scripts/paper/data_compatibility.py [--seed N] [--out DIR] [--window T0 T1] [--zero-shooting single|multiple]

On one simulated 40 s flight record (50 Hz, biased IMU, noisy air data and attitude):
the separator's split against Eq. B8, the two-stage method (stage 1 sweeps the six IMU
biases through the ODE, stage 2 is output-error ML with ln|R|), output error from the zero
initial guess, and the truth. Writes to DIR (default out/data_compatibility): outputs.png
(measured against reconstructed outputs, like the paper's Fig. 7), landscape.png (stage 1),
estimate.json and table.md; prints the wall times. ``--window 500 600`` flies another part
of the flight (100 s there: output error from zero fails by single shooting and succeeds by
``--zero-shooting multiple``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import numpy as np  # noqa: E402

import casest  # noqa: E402
from casest.data import atomic_write_text  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def table(model, est, zero, truth) -> str:
    lines = ["| parameter | unit | two-stage (std) | (estimate - truth) / std | output error from 0 | truth |",
             "|---|---|---|---|---|---|"]
    for i, p in enumerate(model.parameters):
        z = (est.theta[i] - truth[i]) / est.std[i] if np.isfinite(est.std[i]) else np.nan
        lines.append(f"| {p.name} | {p.unit} | {est.theta[i]:.6g} ({est.std[i]:.2g}) | {z:+.2f} | {zero.theta[i]:.6g} "
                     f"| {truth[i]:.6g} |")
    return "\n".join(lines) + "\n"


def plot_outputs(model, data, est, path: str) -> str:
    from casest.apps.plots import pyplot_module, save_png

    plt = pyplot_module()
    _, predicted = model.simulate(est.theta, data)
    t = data.signals[:, 0]
    fig, axes = plt.subplots(3, 2, figsize=(10, 7.5), sharex=True)
    for j, ax in enumerate(axes.T.ravel()):
        scale = 1.0 if j == 0 else 180.0 / np.pi
        unit = "m/s" if j == 0 else "deg"
        ax.plot(t, data.outputs[:, j] * scale, ".", ms=1.5, color="0.6", label="measured")
        ax.plot(t, predicted[:, j] * scale, "-", lw=1.0, color="C3", label="reconstructed (estimate)")
        ax.set_ylabel(f"{model.output_names[j]} [{unit}]")
        if j in (2, 5):
            ax.set_xlabel("t [s]")
    axes[0, 0].legend(fontsize=8, loc="best")
    fig.suptitle("measured and reconstructed outputs (states integrated from the bias-corrected IMU)")
    fig.tight_layout()
    out = save_png(fig, path)
    plt.close(fig)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=os.path.join(HERE, "..", "..", "out", "data_compatibility"))
    parser.add_argument("--window", nargs=2, type=float, metavar=("T0", "T1"), help="flight window in s (default 566 606)")
    parser.add_argument("--zero-shooting", choices=["single", "multiple"], default="single",
                        help="shooting of the output error from zero (multiple: nodes every 250 samples)")
    args = parser.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    dc = casest.load_model_file("data_compatibility")
    if args.window:
        dc.WINDOW = tuple(args.window)
    t_all = time.perf_counter()
    model = dc.model()
    data = dc.simulate(args.seed)
    truth = model.vector(dc.TRUTH)
    part = casest.separate(model)
    eq_b8 = set(part.linear) == set(dc.TRUTH_OUTPUTS) and set(part.nonlinear) == set(dc.TRUTH_IMU)
    print(f"record: {data.n_samples} samples at {dc.RATE:g} Hz, t = {dc.WINDOW[0]:g}-{dc.WINDOW[1]:g} s of the flight")
    print(part.describe())
    print(f"split equals paper Eq. B8 (xi1 = output scale factors and biases, xi2 = IMU biases): {eq_b8}")

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        est = casest.estimate(model, data, sweep_settings=dc.SWEEP_SETTINGS)
    t_two = time.perf_counter() - t0
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        zero = casest.estimate(model, data, start=dc.SINGLE_STAGE_START, mode="full",
                               solver_settings=casest.SolverSettings(shooting=args.zero_shooting, shooting_interval=250))
    t_zero = time.perf_counter() - t0
    z = (est.theta - truth) / est.std
    within = bool(np.all(np.abs(z) < 3))
    print(f"\ntwo-stage: success {est.success} ({est.status}), stage-1 verdict {est.landscape.verdict}: "
          f"{est.landscape.reason}")
    print(f"two-stage: J = {est.cost:.10g}, {t_two:.2f} s (stage 1 {est.timings.get('stage1', 0):.2f} s, "
          f"stage 2 {est.timings.get('stage2', 0):.2f} s, covariance {est.timings.get('uncertainty', 0):.2f} s)")
    print(f"every parameter within 3 std of the truth: {within} (largest |estimate - truth| / std = "
          f"{np.max(np.abs(z)):.2f})")
    print(f"output error from the zero initial guess: success {zero.success}, J = {zero.cost:.10g} "
          f"({zero.cost - est.cost:+.3g} against two-stage), {t_zero:.2f} s")
    print("\n" + table(model, est, zero, truth))
    atomic_write_text(os.path.join(args.out, "table.md"), table(model, est, zero, truth))
    est.to_json(os.path.join(args.out, "estimate.json"))
    try:
        from casest.apps.plots import plot_landscape

        print("figures:", plot_outputs(model, data, est, os.path.join(args.out, "outputs.png")),
              plot_landscape(est.landscape, os.path.join(args.out, "landscape.png"),
                             title=f"stage 1 over the six IMU biases: {est.landscape.verdict}"))
    except ImportError as err:
        print(f"figures skipped ({err}); pip install 'casest[plot]'")
    print(f"wall time {time.perf_counter() - t_all:.2f} s")
    return 0 if est.success and eq_b8 and within else 1


if __name__ == "__main__":
    sys.exit(main())
