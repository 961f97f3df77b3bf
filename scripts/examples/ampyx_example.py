#!/usr/bin/env python3
"""The Ampyx AP2 flight record, end to end: air-data calibration, flight-path reconstruction
and rate responses, each estimated on part of the record and validated on the rest.

    python3 scripts/examples/ampyx_example.py [--out DIR] [--no-figures]

The record is the bundled ``data/ampyx_ap2`` file as published (Ampyx Power AP2 flight data,
courtesy of Ampyx Power B.V. and the TU Delft Airborne Wind Energy group, Apache License 2.0),
read by struct paths. The 49 s are cut into three segments of about 16 s (s1 and s2 traction
phase and transition, s3 retraction phase):

1. air-data calibration (``models/ampyx_air_data.py``, the paper's Sec. IV form) by the two-stage
   method on s1 + s2, its stage-1 landscape, validated on s3;
2. flight-path reconstruction (``casest.flight_path_model``: Euler kinematics from the rates,
   position from the NED velocity) on s1 and s2 as two manoeuvres, validated on s3;
3. rate responses (``models/ampyx_rates.py``) by output error with an input delay on s1 and s2,
   validated on s3.

Each part prints its estimates with the ML and the colored-residual std and which one stands
(:meth:`casest.Estimate.std_choice`), the correlations, the residual analysis, the
validation metrics and the iterations; figures go to DIR (default: a new folder ``casest_figures``
in the working directory; the docs' own figures: ``--out docs/figures``):
``ampyx_<part>_{fit,residuals,convergence,match,correlation}.png`` and ``ampyx_air_data_landscape.png``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import numpy as np  # noqa: E402

import casest  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
WINDOWS = {"s1": (0.0, 16.4), "s2": (16.4, 32.8), "s3": (32.8, 49.4)}


def parameter_table(est) -> str:
    """Estimates with the ML std, the colored-residual std, their ratio and the std that stands."""
    choice = est.std_choice()
    colored = (est.residual_analysis.colored_std if est.residual_analysis is not None
               else np.full(len(est.theta), np.nan))
    units = est.parameter_units or ("",) * len(est.theta)
    lines = [f"{'parameter':>10} {'value':>13} {'ML std':>10} {'colored std':>12} {'ratio':>6}  unit",
             "-" * 64]
    for name, value, std, c, unit in zip(est.parameter_names, est.theta, est.std, colored, units):
        lines.append(f"{name:>10} {value:>13.6g} {std:>10.3g} {c:>12.3g} {c / std if std > 0 else np.nan:>6.2f}  "
                     f"{unit}")
    lines.append(f"std reported: {choice.kind} ({choice.reason})")
    return "\n".join(lines)


def correlations(est, threshold: float = 0.9) -> str:
    names, C = est.parameter_names, est.correlation
    pairs = [(abs(C[i, j]), names[i], names[j], C[i, j]) for i in range(len(names)) for j in range(i)
             if np.isfinite(C[i, j]) and abs(C[i, j]) > threshold]
    if not pairs:
        return f"correlations: none above {threshold}"
    return f"correlations above {threshold}: " + ", ".join(f"{a}-{b} {c:+.3f}" for _, a, b, c in sorted(pairs)[::-1])


def report_part(title: str, est, validation, seconds: float) -> None:
    print(f"\n=== {title} ===")
    print(f"success {est.success}, {est.n_iterations} iterations, cost {est.cost:.6g}, {seconds:.1f} s")
    print(parameter_table(est))
    print(correlations(est))
    if est.residual_analysis is not None:
        print("\n".join(est.residual_analysis.describe()))
    print(validation.report("Validation on s3 (held out)"))
    print("conclusion:", est.conclusion()[1][:300])


def figures(part: str, model, est, records, validation, out: str) -> list:
    from casest.estimation.figures import save_figure, validation_figure

    paths = [save_figure(est.plot_fit(model, records), os.path.join(out, f"ampyx_{part}_fit.png")),
             save_figure(est.plot_residuals(model, records), os.path.join(out, f"ampyx_{part}_residuals.png")),
             save_figure(validation_figure(validation, "s3, held out"), os.path.join(out, f"ampyx_{part}_match.png")),
             save_figure(est.plot_correlation(), os.path.join(out, f"ampyx_{part}_correlation.png"))]
    if est.convergence is not None:
        paths.append(save_figure(est.plot_convergence(), os.path.join(out, f"ampyx_{part}_convergence.png")))
    return paths


def air_data(out: str | None) -> float:
    module = casest.load_model_file("ampyx_air_data")
    model = module.model()
    t0 = time.perf_counter()
    train = module.load((WINDOWS["s1"][0], WINDOWS["s2"][1]))
    est = casest.estimate(model, train, sweep_settings=module.SWEEP_SETTINGS,
                          solver_settings=casest.SolverSettings(record_iterates=True))
    validation = est.validate(model, module.load(WINDOWS["s3"]))
    seconds = time.perf_counter() - t0
    report_part("1. Air-data calibration (two-stage, s1 + s2)", est, validation, seconds)
    print(f"stage 1: verdict {est.landscape.verdict}, {len(est.landscape.candidates)} candidates")
    if out:
        from casest.apps.plots import plot_landscape

        names = figures("air_data", model, est, train, validation, out)
        names.append(plot_landscape(est.landscape, os.path.join(out, "ampyx_air_data_landscape.png"),
                                    title="AP2 air data: stage 1"))
        print("wrote", ", ".join(os.path.basename(n) for n in names))
    return seconds


def _measured(window) -> dict:
    """The arrays the flight-path model needs, read from the record by struct paths."""
    fields = {"t": "controls.times", "p": "response.w[0]", "q": "response.w[1]", "r": "response.w[2]",
              "phi": "response.rollPitchYaw[0]", "theta": "response.rollPitchYaw[1]",
              "psi": "response.rollPitchYaw[2]", "V_N": "response.v[0]", "V_E": "response.v[1]",
              "V_D": "response.v[2]", "x_N": "response.p[0]", "x_E": "response.p[1]", "x_D": "response.p[2]"}
    arrays = casest.read_mat_paths(casest.bundled_data_dir("ampyx_ap2", "validationDataFC114_1_v2_pc.mat"),
                                   {k: f"validationData.{v}" for k, v in fields.items()})
    keep = (arrays["t"] >= window[0]) & (arrays["t"] < window[1])
    return {k: v[keep] for k, v in arrays.items()}


def flight_path(out: str | None) -> float:
    model = casest.flight_path_model()
    t0 = time.perf_counter()
    records = {name: model.dataset(casest.flight_path_columns(model, _measured(WINDOWS[name])))
               for name in ("s1", "s2")}
    est = casest.estimate(model, records)
    validation = est.validate(model, model.dataset(casest.flight_path_columns(model, _measured(WINDOWS["s3"]))))
    seconds = time.perf_counter() - t0
    report_part("2. Flight-path reconstruction (output error, s1 and s2)", est, validation, seconds)
    if out:
        names = figures("flight_path", model, est, records, validation, out)
        print("wrote", ", ".join(os.path.basename(n) for n in names))
    return seconds


def rates(out: str | None) -> float:
    module = casest.load_model_file("ampyx_rates")
    model = module.model()
    t0 = time.perf_counter()
    records = module.segments({name: WINDOWS[name] for name in ("s1", "s2")})
    est = casest.estimate(model, records, sweep_settings=module.SWEEP_SETTINGS)
    validation = est.validate(model, module.load(WINDOWS["s3"]))
    seconds = time.perf_counter() - t0
    report_part("3. Rate responses (output error with an input delay, s1 and s2)", est, validation, seconds)
    if out:
        names = figures("rates", model, est, records, validation, out)
        print("wrote", ", ".join(os.path.basename(n) for n in names))
    return seconds


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=os.path.join(os.getcwd(), "casest_figures"),
                        help="folder of the figures (default: casest_figures in the working directory)")
    parser.add_argument("--no-figures", action="store_true", help="print the tables only")
    args = parser.parse_args(argv)
    out = None if args.no_figures else args.out
    start = time.perf_counter()
    times = {"air data": air_data(out), "flight path": flight_path(out), "rates": rates(out)}
    print("\ntimes (s): " + ", ".join(f"{k} {v:.1f}" for k, v in times.items())
          + f"; whole example {time.perf_counter() - start:.1f} s in this process")
    return 0


if __name__ == "__main__":
    sys.exit(main())
