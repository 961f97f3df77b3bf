#!/usr/bin/env python3
"""Per-step time of casest's generated C EKF (``casest.export_c``) in a C loop, against a
hand-written numba EKF of the same filter, both warm, on the same record: the pendulum
(``ekf_numba_peer.py``: the 2x2 algebra written out by hand) or the 9-state aircraft
(``aircraft_ekf_peer.py``: its Jacobian derived by hand; its states checked against casest's).

    python3 scripts/benchmarks/bench_export_c.py [--samples 100000] [--runs 5]
    python3 scripts/benchmarks/bench_export_c.py --model aircraft [--samples 10000] [--runs 5]

The generated step is compiled with ``cc -O2`` and called through its C API
(``NAME_step``, then ``NAME_state``) from a C loop over the record held in memory; the numba pass
runs the same record (its first call compiles, untimed). Each run times the whole record; the
figure is the median of ``--runs`` runs per step, with the range. Needs a C compiler and numba.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))
sys.path.insert(0, HERE)

import casest  # noqa: E402
from casest.filters.compiled_passes import record_columns  # noqa: E402

import aircraft_ekf_peer  # noqa: E402
import ekf_numba_peer  # noqa: E402
from bench_filters import P0, Q_RATE, R_VAR, THETA, pendulum, record  # noqa: E402

#: the C compiler's flags (``--cflags``)
C_FLAGS = ["-O2"]

TIMER = r"""
#define _POSIX_C_SOURCE 199309L  /* clock_gettime */
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "NAME.h"
#define NX UPPER_N_STATES
#define NY UPPER_N_OUTPUTS
#define NU UPPER_N_INPUTS
#define NUK UPPER_N_STEP_INPUTS
#define ND (2 * NY + NU + 2 * NUK + 1)
static void read(double *v, int n) { for (int i = 0; i < n; ++i) if (scanf("%lf", &v[i]) != 1) exit(3); }
int main(void) {
  int N, runs, k, r;
  if (scanf("%d %d", &N, &runs) != 2) return 3;
  static double x0[NX], P0[NX * NX], theta[UPPER_N_PARAMETERS], Qc[NX * NX], noise[NU + 1], R[NY * NY];
  double *d = malloc(sizeof(double) * (size_t)N * ND), sum = 0.0;  /* the record, outside the filter */
  read(x0, NX); read(P0, NX * NX); read(theta, UPPER_N_PARAMETERS); read(Qc, NX * NX); read(noise, NU); read(R, NY * NY);
  read(d, N * ND);
  for (r = 0; r < runs; ++r) {
    NAME_t f;
    struct timespec a, b;
    NAME_init(&f, x0, P0, theta, Qc, noise, R);
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (k = 0; k < N; ++k) {
      const double *row = d + (size_t)k * ND;
      NAME_step(&f, row, NULL, row + 2 * NY, row + 2 * NY + NU, row + 2 * NY + NU + NUK, row[ND - 1]);
      sum += NAME_state(&f)[0];
    }
    clock_gettime(CLOCK_MONOTONIC, &b);
    printf("%.9f\n", (b.tv_sec - a.tv_sec) + 1e-9 * (b.tv_nsec - a.tv_nsec));
  }
  fprintf(stderr, "checksum %.17g\n", sum);
  free(d);
  return 0;
}
"""


def c_times(ekf, data, runs: int, folder: str, name: str = "pend") -> list:
    """Seconds per record of the generated C step, one per run."""
    cc = shutil.which("cc") or shutil.which("gcc")
    paths = casest.export_c(ekf, folder, name=name)
    timer = os.path.join(folder, "timer.c")
    with open(timer, "w") as fh:
        fh.write(TIMER.replace("UPPER", name.upper()).replace("NAME", name))
    exe = os.path.join(folder, "timer")
    subprocess.run([cc, "-std=c99", *C_FLAGS, f"-I{folder}", timer, paths["source"], "-lm", "-o", exe], check=True)
    D, _ = record_columns(ekf.model, data)
    numbers = [*ekf.x0, *ekf.P0.reshape(-1, order="F"), *ekf.theta, *ekf.Qc.reshape(-1, order="F"), *ekf.input_noise,
               *ekf.R.reshape(-1, order="F")]
    text = f"{data.n_samples} {runs}\n" + " ".join(repr(float(v)) for v in numbers) + "\n" + \
        "\n".join(" ".join(repr(float(v)) for v in row) for row in D)
    run = subprocess.run([exe], input=text, capture_output=True, text=True, check=True)
    return [float(line) for line in run.stdout.split()]


def numba_times(data, runs: int) -> list:
    """Seconds per record of the numba pendulum EKF, one per run (its first call compiles, untimed)."""
    nb = ekf_numba_peer.ekf_pass_factory()
    Y, U = data.outputs, data.signals[:, 1]
    nb(Y, U, THETA["c"], THETA["L"], Q_RATE, R_VAR, P0[0, 0])  # compile, untimed
    out = []
    for _ in range(runs):
        t = time.perf_counter()
        nb(Y, U, THETA["c"], THETA["L"], Q_RATE, R_VAR, P0[0, 0])
        out.append(time.perf_counter() - t)
    return out


def aircraft_case(samples: int):
    """The 9-state aircraft EKF (``models/aircraft.py``'s output-error model at the true
    coefficients and biases) on a simulated flight of ``samples`` samples at 50 Hz, and the
    arguments of the hand-written numba pass (:mod:`aircraft_ekf_peer`)."""
    from casest.apps.sim import aircraft as ac

    air = casest.load_model_file("aircraft")
    model = air.output_error_model()
    record = ac.simulate(0, duration=(samples - 1) / 50.0)
    data = air.output_error_dataset(record, record.states[0, :9])
    theta = {**ac.TRUE_COEFFICIENTS, **dict(zip(("l_x", "l_y", "l_z", "l_p", "l_q", "l_r"), ac.IMU_BIAS))}
    R = [0.5, 0.01, 0.01, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 0.05, 0.05, 0.05]
    Qc = dict(zip(model.state_names, [0.1, 0.1, 0.1, 1e-3, 1e-3, 1e-3, 1e-5, 1e-5, 1e-5]))
    P0_ = np.diag([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3])
    x0 = record.states[0, :9].astype(float)
    ekf = casest.ExtendedKalmanFilter(model, theta, Qc, R, P0_, x0=x0)
    U = np.column_stack([data.column(n) for n in ac.CONTROLS])
    dt = float(data.signals[1, 0] - data.signals[0, 0])
    args = (data.outputs, U, dt, aircraft_ekf_peer.coefficient_vector(theta), aircraft_ekf_peer.bias_vector(theta),
            ekf.Qc, ekf.R, x0, P0_)
    return ekf, data, args


def aircraft_numba_times(ekf, data, args, runs: int) -> list:
    """Seconds per record of the hand-written numba aircraft EKF, one per run; its states are first
    checked against casest's filter (1e-9 of each state's range)."""
    nb = aircraft_ekf_peer.ekf_pass_factory()
    x = nb(*args)  # compile, untimed
    reference = ekf.filter(data).x_filtered
    worst = float(np.max(np.abs(x - reference) / np.maximum(np.ptp(reference, axis=0), 1e-12)))
    if not worst <= 1e-9:
        raise SystemExit(f"the numba peer's states differ from casest's filter by {worst:.3g} of their range")
    out = []
    for _ in range(runs):
        t = time.perf_counter()
        nb(*args)
        out.append(time.perf_counter() - t)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", choices=("pendulum", "aircraft"), default="pendulum")
    parser.add_argument("--samples", type=int, help="default: 100000 (pendulum), 10000 (aircraft)")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--cflags", default="-O2", help="the C compiler's optimisation flags (default -O2)")
    args = parser.parse_args(argv)
    C_FLAGS[:] = args.cflags.split()
    if not (shutil.which("cc") or shutil.which("gcc")) or not ekf_numba_peer.available():
        print("needs a C compiler and numba (pip install numba)")
        return 1
    samples = args.samples or (100_000 if args.model == "pendulum" else 10_000)
    if args.model == "pendulum":
        model = pendulum()
        data = record(model, samples, seed=0)
        ekf = casest.ExtendedKalmanFilter(model, THETA, {"rate": Q_RATE}, [R_VAR, R_VAR], P0, x0=np.array([1.0, 0.0]))
        title = "pendulum EKF (2 states, 2 outputs)"
    else:
        ekf, data, peer_args = aircraft_case(samples)
        title = "aircraft EKF (9 states, 12 outputs)"
    with tempfile.TemporaryDirectory(prefix="casest_export_bench_") as folder:
        c = c_times(ekf, data, args.runs, folder, name="pend" if args.model == "pendulum" else "acft")
    nb = numba_times(data, args.runs) if args.model == "pendulum" else aircraft_numba_times(ekf, data, peer_args, args.runs)
    per = {name: [1e9 * t / samples for t in times] for name, times in (("generated C", c), ("numba", nb))}
    load = os.getloadavg()[0]
    print(f"{title}, {samples} samples, {args.runs} runs, {datetime.date.today()}, load {load:.2f}, "
          f"{platform.processor() or platform.machine()}")
    for name, values in per.items():
        print(f"  {name:12s} {statistics.median(values):8.1f} ns/step (range {min(values):.1f}-{max(values):.1f})")
    ratios = [a / b for a, b in zip(per["generated C"], per["numba"])]
    print(f"  generated C / numba: median {statistics.median(ratios):.2f} (range {min(ratios):.2f}-{max(ratios):.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
