#!/usr/bin/env python3
"""Per-step time of casest's generated C EKF (``casest.export_c``) in a C loop, against the numba
EKF peer of the same pendulum filter (``ekf_numba_peer.py``: the 2x2 algebra written out by hand),
both warm, on the same record.

    python3 scripts/benchmarks/bench_export_c.py [--samples 100000] [--runs 5]

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
from casest.state.compiled_passes import record_columns  # noqa: E402

import ekf_numba_peer  # noqa: E402
from bench_filters import P0, Q_RATE, R_VAR, THETA, pendulum, record  # noqa: E402

TIMER = r"""
#define _POSIX_C_SOURCE 199309L  /* clock_gettime */
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "pend.h"
#define ND (2 * PEND_N_OUTPUTS + PEND_N_INPUTS + 2 * PEND_N_STEP_INPUTS + 1)
int main(int argc, char **argv) {
  int N, runs, k, r;
  if (scanf("%d %d", &N, &runs) != 2) return 3;
  double x0[2], P0[4], theta[2], Qc[4], noise[1], R[4];
  double *d = malloc(sizeof(double) * (size_t)N * ND), sum = 0.0;  /* the record, outside the filter */
  for (k = 0; k < 2; ++k) if (scanf("%lf", &x0[k]) != 1) return 3;
  for (k = 0; k < 4; ++k) if (scanf("%lf", &P0[k]) != 1) return 3;
  for (k = 0; k < 2; ++k) if (scanf("%lf", &theta[k]) != 1) return 3;
  for (k = 0; k < 4; ++k) if (scanf("%lf", &Qc[k]) != 1) return 3;
  if (scanf("%lf", &noise[0]) != 1) return 3;
  for (k = 0; k < 4; ++k) if (scanf("%lf", &R[k]) != 1) return 3;
  for (k = 0; k < N * ND; ++k) if (scanf("%lf", &d[k]) != 1) return 3;
  const int ny = PEND_N_OUTPUTS, nu = PEND_N_INPUTS, nuk = PEND_N_STEP_INPUTS;
  for (r = 0; r < runs; ++r) {
    pend_t f;
    struct timespec a, b;
    pend_init(&f, x0, P0, theta, Qc, noise, R);
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (k = 0; k < N; ++k) {
      const double *row = d + (size_t)k * ND;
      pend_step(&f, row, NULL, row + 2 * ny, row + 2 * ny + nu, row + 2 * ny + nu + nuk, row[ND - 1]);
      sum += pend_state(&f)[0];
    }
    clock_gettime(CLOCK_MONOTONIC, &b);
    printf("%.9f\n", (b.tv_sec - a.tv_sec) + 1e-9 * (b.tv_nsec - a.tv_nsec));
  }
  fprintf(stderr, "checksum %.17g\n", sum);
  free(d);
  return 0;
}
"""


def c_times(ekf, data, runs: int, folder: str) -> list:
    """Seconds per record of the generated C step, one per run."""
    cc = shutil.which("cc") or shutil.which("gcc")
    paths = casest.export_c(ekf, folder, name="pend")
    timer = os.path.join(folder, "timer.c")
    with open(timer, "w") as fh:
        fh.write(TIMER)
    exe = os.path.join(folder, "timer")
    subprocess.run([cc, "-std=c99", "-O2", f"-I{folder}", timer, paths["source"], "-lm", "-o", exe], check=True)
    D, _ = record_columns(ekf.model, data)
    numbers = [*ekf.x0, *ekf.P0.reshape(-1, order="F"), *ekf.theta, *ekf.Qc.reshape(-1, order="F"), *ekf.input_noise,
               *ekf.R.reshape(-1, order="F")]
    text = f"{data.n_samples} {runs}\n" + " ".join(repr(float(v)) for v in numbers) + "\n" + \
        "\n".join(" ".join(repr(float(v)) for v in row) for row in D)
    run = subprocess.run([exe], input=text, capture_output=True, text=True, check=True)
    return [float(line) for line in run.stdout.split()]


def numba_times(data, runs: int) -> list:
    nb = ekf_numba_peer.ekf_pass_factory()
    Y, U = data.outputs, data.signals[:, 1]
    nb(Y, U, THETA["c"], THETA["L"], Q_RATE, R_VAR, P0[0, 0])  # compile, untimed
    out = []
    for _ in range(runs):
        t = time.perf_counter()
        nb(Y, U, THETA["c"], THETA["L"], Q_RATE, R_VAR, P0[0, 0])
        out.append(time.perf_counter() - t)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=100_000)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args(argv)
    if not (shutil.which("cc") or shutil.which("gcc")) or not ekf_numba_peer.available():
        print("needs a C compiler and numba (pip install numba)")
        return 1
    model = pendulum()
    data = record(model, args.samples, seed=0)
    ekf = casest.ExtendedKalmanFilter(model, THETA, {"rate": Q_RATE}, [R_VAR, R_VAR], P0, x0=np.array([1.0, 0.0]))
    with tempfile.TemporaryDirectory(prefix="casest_export_bench_") as folder:
        c = c_times(ekf, data, args.runs, folder)
    nb = numba_times(data, args.runs)
    per = {name: [1e9 * t / args.samples for t in times] for name, times in (("generated C", c), ("numba", nb))}
    load = os.getloadavg()[0]
    print(f"pendulum EKF, {args.samples} samples, {args.runs} runs, {datetime.date.today()}, load {load:.2f}, "
          f"{platform.processor() or platform.machine()}")
    for name, values in per.items():
        print(f"  {name:12s} {statistics.median(values):8.1f} ns/step (range {min(values):.1f}-{max(values):.1f})")
    ratios = [a / b for a, b in zip(per["generated C"], per["numba"])]
    print(f"  generated C / numba: median {statistics.median(ratios):.2f} (range {min(ratios):.2f}-{max(ratios):.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
