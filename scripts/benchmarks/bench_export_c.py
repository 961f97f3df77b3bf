#!/usr/bin/env python3
"""Per-step CPU time of casest's generated C filters (``casest.export_c``) against hand-written C
filters of the same models (``scripts/benchmarks/hand_c/``), interleaved in one process, both
called once per sample through a step function over a state struct, as a flight computer calls
a filter.

    python3 scripts/benchmarks/bench_export_c.py [--samples 100000] [--runs 7] [--beside N]
    python3 scripts/benchmarks/bench_export_c.py --model aircraft [--samples 10000] [--runs 7] [--beside N]

The pendulum (2 states, 2 outputs) and the 9-state aircraft (12 outputs): the EKF (its Jacobian
derived by hand in the hand-written filters) and the UKF (alpha 1, beta 2, kappa 0). Every
filter is compiled with the same ``cc`` flags (``--cflags``, default -O2) into one C program that
holds the record in memory and runs each contender over the whole record, writing x(k|k) at every
sample, once per run; the contenders' order is reversed at every run, and each is timed with the
process's CPU clock (``CLOCK_PROCESS_CPUTIME_ID``). The generated filters are called through
their C API (``NAME_step``, ``NAME_state``), with every check of the flight semantics in place.
Before timing, each hand-written filter's states are checked against the generated one's
(1e-9 of each state's range). Prints the median and range of each contender's ns per step and of
the ratio generated / hand-written per run, with the date and the load. ``--beside N`` runs the
program beside N CPU-bound processes (``busy.py``), a busy machine. Needs a C compiler.
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

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))
sys.path.insert(0, HERE)

import casest  # noqa: E402
from casest.filters.compiled_passes import record_columns  # noqa: E402

from bench_filters import P0, Q_RATE, R_VAR, THETA, pendulum, record  # noqa: E402
from busy import cpu_bound_processes  # noqa: E402

HAND = os.path.join(HERE, "hand_c")
#: the UKFs' spread (beta 2, kappa 0): at alpha = 1 the weights are of order 1, so the two filters'
#: roundings stay at 1e-14 of the states' range (at 1e-3, weights of 1e6 on 9 states, they part by
#: 3e-8 over 3000 samples of the aircraft although both are the same filter)
UKF_ALPHA = 1.0

HARNESS = r"""
#define _POSIX_C_SOURCE 199309L  /* clock_gettime */
#include <stdio.h>
#include <stdlib.h>
#include <math.h>
#include <time.h>
#include "hand.h"
INCLUDES
static int N;
static double cpu(void) {
  struct timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}
static double *doubles(int n) {
  double *v = malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
  for (int i = 0; i < n; ++i) if (scanf("%lf", &v[i]) != 1) exit(3);
  return v;
}
DECLARATIONS
int main(int argc, char **argv) {
  int runs = atoi(argv[1]), r, i, c;
  if (scanf("%d", &N) != 1) return 3;
  READS
  const char *names[] = {NAMES};
  void (*runs_of[])(double *) = {FUNCTIONS};
  const int width[] = {WIDTHS}, pair[] = {PAIRS}, count = (int)(sizeof width / sizeof width[0]);
  double *out[16];
  for (c = 0; c < count; ++c) { out[c] = malloc(sizeof(double) * (size_t)N * (size_t)width[c]); runs_of[c](out[c]); }
  for (c = 0; c < count; ++c) if (pair[c] >= 0) {  /* the hand-written filter against the generated one */
    double worst = 0.0;
    for (i = 0; i < width[c]; ++i) {
      double lo = INFINITY, hi = -INFINITY, diff = 0.0;
      for (int k = 0; k < N; ++k) {
        double a = out[pair[c]][(size_t)k * (size_t)width[c] + (size_t)i], b = out[c][(size_t)k * (size_t)width[c] + (size_t)i];
        lo = a < lo ? a : lo; hi = a > hi ? a : hi; diff = fabs(a - b) > diff ? fabs(a - b) : diff;
      }
      worst = diff / (hi - lo > 0.0 ? hi - lo : 1.0) > worst ? diff / (hi - lo > 0.0 ? hi - lo : 1.0) : worst;
    }
    printf("check %s %.3g\n", names[c], worst);
  }
  for (r = 0; r < runs; ++r)
    for (int j = 0; j < count; ++j) {
      c = r % 2 == 0 ? j : count - 1 - j;  /* the order reversed at every run */
      double t = cpu();
      runs_of[c](out[c]);
      printf("time %s %d %.9f\n", names[c], r, cpu() - t);
    }
  return 0;
}
"""

GENERATED_RUN = r"""
static double *NAME_args, *NAME_rows;
static void run_NAME(double *out) {
  static NAME_t f;
  const int nx = UP_N_STATES, ny = UP_N_OUTPUTS, nu = UP_N_INPUTS, nuk = UP_N_STEP_INPUTS;
  const int nd = 2 * ny + nu + 2 * nuk + 1, np = UP_N_PARAMETERS;
  const double *a = NAME_args;
  if (NAME_init(&f, a, a + nx, a + nx + nx * nx, a + nx + nx * nx + np, a + nx + 2 * nx * nx + np,
                a + nx + 2 * nx * nx + np + nu, 0.0) != UP_OK) exit(4);
  for (int k = 0; k < N; ++k) {
    const double *row = NAME_rows + (size_t)k * (size_t)nd;
    (void)NAME_step(&f, row, NULL, row + 2 * ny, row + 2 * ny + nu, row + 2 * ny + nu + nuk, row[nd - 1]);
    const double *x = NAME_state(&f);
    for (int i = 0; i < nx; ++i) out[(size_t)k * (size_t)nx + (size_t)i] = x[i];
  }
}
"""


def generated_contender(flt, data, name: str, folder: str) -> dict:
    """The generated filter as a contender: its export, its C run function and the numbers it reads."""
    paths = casest.export_c(flt, folder, name=name)
    D, _ = record_columns(flt.model, data)
    noise = getattr(flt, "input_noise", np.zeros(len(flt.model.inputs)))
    args = [*flt.x0, *flt.P0.reshape(-1, order="F"), *flt.theta, *flt.Qc.reshape(-1, order="F"), *noise,
            *flt.R.reshape(-1, order="F")]
    return {"name": name, "source": paths["source"], "include": f'#include "{name}.h"',
            "declaration": GENERATED_RUN.replace("UP_", name.upper() + "_").replace("NAME", name),
            "reads": [(f"{name}_args", len(args)), (f"{name}_rows", "N * " + str(D.shape[1]))],
            "numbers": [args, D.reshape(-1)], "width": flt.model.n_states, "pair": None}


def hand_contender(name: str, run_body: str, inputs: list, width: int, pair: str) -> dict:
    """A hand-written filter as a contender: ``run_body`` (C, in ``run_NAME(double *out)``) uses the
    arrays ``NAME_key`` of ``inputs`` ``[(key, values)]``."""
    reads = [(f"{name}_{key}", len(np.ravel(values))) for key, values in inputs]
    declaration = "".join(f"static double *{r[0]};\n" for r in reads) + \
        f"static void run_{name}(double *out) {{\n{run_body}\n}}\n"
    return {"name": name, "source": None, "include": "", "declaration": declaration, "reads": reads,
            "numbers": [np.ravel(values) for _, values in inputs], "width": width, "pair": pair}


def pendulum_contenders(samples: int, folder: str) -> tuple[list, str]:
    model = pendulum()
    data = record(model, samples, seed=0)
    args = (model, THETA, {"rate": Q_RATE}, [R_VAR, R_VAR], P0)
    ekf = casest.ExtendedKalmanFilter(*args, x0=np.array([1.0, 0.0]))
    ukf = casest.UnscentedKalmanFilter(*args, x0=np.array([1.0, 0.0]), alpha=UKF_ALPHA)
    Y, U = data.outputs, data.signals[:, 1]
    common = [("Y", Y), ("U", U)]
    scalars = f"{THETA['c']!r}, {THETA['L']!r}, {Q_RATE!r}, {R_VAR!r}, {float(P0[0, 0])!r}"
    contenders = []
    for kind, flt, extra in (("ekf", ekf, ""), ("ukf", ukf, f", {UKF_ALPHA!r}, 2.0, 0.0")):
        body = (f"  static hand_pendulum_t s;\n  hand_pendulum_init(&s, {scalars});\n"
                f"  for (int k = 0; k < N; ++k) {{\n"
                f"    hand_pendulum_{kind}_step(&s, hand_{kind}_Y + 2 * (size_t)k, hand_{kind}_U[k]{extra});\n"
                f"    out[2 * (size_t)k] = s.xf0;\n    out[2 * (size_t)k + 1] = s.xf1;\n  }}")
        contenders += [generated_contender(flt, data, f"gen_{kind}", folder),
                       hand_contender(f"hand_{kind}", body, common, 2, f"gen_{kind}")]
    return contenders, "pendulum (2 states, 2 outputs)"


def aircraft_contenders(samples: int, folder: str) -> tuple[list, str]:
    from casest.apps.sim import aircraft as ac

    air = casest.load_model_file("aircraft")
    model = air.output_error_model()
    flight = ac.simulate(0, duration=(samples - 1) / 50.0)
    data = air.output_error_dataset(flight, flight.states[0, :9])
    theta = {**ac.TRUE_COEFFICIENTS, **dict(zip(("l_x", "l_y", "l_z", "l_p", "l_q", "l_r"), ac.IMU_BIAS))}
    R = [0.5, 0.01, 0.01, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 0.05, 0.05, 0.05]
    Qc = dict(zip(model.state_names, [0.1, 0.1, 0.1, 1e-3, 1e-3, 1e-3, 1e-5, 1e-5, 1e-5]))
    P0_ = np.diag([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3])
    x0 = flight.states[0, :9].astype(float)
    ekf = casest.ExtendedKalmanFilter(model, theta, Qc, R, P0_, x0=x0)
    U = np.column_stack([data.column(n) for n in ac.CONTROLS])
    dt = float(data.signals[1, 0] - data.signals[0, 0])
    frame = np.concatenate([[ac.G, ac.AIRFRAME.rho, ac.AIRFRAME.S, ac.AIRFRAME.b, ac.AIRFRAME.cbar, ac.AIRFRAME.mass],
                            ac.AIRFRAME.inertia.reshape(-1), np.linalg.inv(ac.AIRFRAME.inertia).reshape(-1)])
    inputs = [("Y", data.outputs), ("U", U), ("c", [theta[k] for k in ac.COEFFICIENTS]),
              ("bias", [theta[k] for k in ("l_x", "l_y", "l_z", "l_p", "l_q", "l_r")]),
              ("Qc", ekf.Qc.reshape(-1, order="F")), ("R", ekf.R.reshape(-1, order="F")), ("x0", x0),
              ("P0", P0_.reshape(-1, order="F")), ("frame", frame)]
    ukf = casest.UnscentedKalmanFilter(model, theta, Qc, R, P0_, x0=x0, alpha=UKF_ALPHA)
    contenders = []
    for kind, flt, extra in (("ekf", ekf, ""), ("ukf", ukf, f", {UKF_ALPHA!r}, 2.0, 0.0")):
        names = ", ".join(f"hand_{kind}_{k}" for k, _ in inputs[2:])
        body = (f"  static hand_aircraft_t s;\n  hand_aircraft_init(&s, {dt!r}, {names});\n"
                f"  for (int k = 0; k < N; ++k) {{\n"
                f"    const double *u = hand_{kind}_U + 4 * (size_t)k;\n"
                f"    hand_aircraft_{kind}_step(&s, hand_{kind}_Y + 12 * (size_t)k, u, k + 1 < N ? u + 4 : u{extra});\n"
                f"    for (int i = 0; i < 9; ++i) out[9 * (size_t)k + (size_t)i] = s.xf[i];\n  }}")
        contenders += [generated_contender(flt, data, f"gen_{kind}", folder),
                       hand_contender(f"hand_{kind}", body, inputs, 9, f"gen_{kind}")]
    return contenders, "aircraft (9 states, 12 outputs)"


def run_harness(contenders: list, runs: int, folder: str, cflags: list, samples: int) -> tuple[dict, dict]:
    """Compile and run the program; ``({name: [seconds per run]}, {name: check})``."""
    cc = shutil.which("cc") or shutil.which("gcc")
    names = [c["name"] for c in contenders]
    reads = "\n  ".join(f"{var} = doubles({count});" for c in contenders for var, count in c["reads"])
    text = (HARNESS.replace("INCLUDES", "\n".join(c["include"] for c in contenders if c["include"]))
            .replace("DECLARATIONS", "\n".join(c["declaration"] for c in contenders))
            .replace("READS", reads).replace("NAMES", ", ".join(f'"{n}"' for n in names))
            .replace("FUNCTIONS", ", ".join(f"run_{n}" for n in names))
            .replace("WIDTHS", ", ".join(str(c["width"]) for c in contenders))
            .replace("PAIRS", ", ".join(str(names.index(c["pair"]) if c["pair"] else -1) for c in contenders)))
    harness, exe = os.path.join(folder, "harness.c"), os.path.join(folder, "harness")
    with open(harness, "w") as fh:
        fh.write(text)
    sources = [c["source"] for c in contenders if c["source"]]
    hand_sources = [os.path.join(HAND, f) for f in sorted(os.listdir(HAND)) if f.endswith(".c")]
    subprocess.run([cc, "-std=c99", *cflags, f"-I{folder}", f"-I{HAND}", harness, *sources, *hand_sources, "-lm", "-o",
                    exe], check=True)
    numbers = [str(samples)] + [" ".join(repr(float(v)) for v in block) for c in contenders for block in c["numbers"]]
    run = subprocess.run([exe, str(runs)], input="\n".join(numbers), capture_output=True, text=True, check=True)
    times, checks = {n: [] for n in names}, {}
    for line in run.stdout.splitlines():
        parts = line.split()
        if parts[0] == "check":
            checks[parts[1]] = float(parts[2])
        else:
            times[parts[1]].append(float(parts[3]))
    return times, checks


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", choices=("pendulum", "aircraft"), default="pendulum")
    parser.add_argument("--samples", type=int, help="default: 100000 (pendulum), 10000 (aircraft)")
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--cflags", default="-O2", help="the C compiler's optimisation flags (default -O2)")
    parser.add_argument("--beside", type=int, default=0, help="run beside this many CPU-bound processes")
    args = parser.parse_args(argv)
    if not (shutil.which("cc") or shutil.which("gcc")):
        print("needs a C compiler (cc or gcc)")
        return 1
    samples = args.samples or (100_000 if args.model == "pendulum" else 10_000)
    with tempfile.TemporaryDirectory(prefix="casest_export_bench_") as folder:
        contenders, title = (pendulum_contenders if args.model == "pendulum" else aircraft_contenders)(samples, folder)
        with cpu_bound_processes(args.beside):
            load_before = os.getloadavg()[0]
            times, checks = run_harness(contenders, args.runs, folder, args.cflags.split(), samples)
            load_after = os.getloadavg()[0]
    for name, worst in checks.items():
        if not worst <= 1e-9:
            raise SystemExit(f"{name}'s states differ from the generated filter's by {worst:.3g} of their range")
    print(f"{title}, {samples} samples, {args.runs} runs (order reversed each run), CPU time, cc {args.cflags}, "
          f"{datetime.date.today()}, beside {args.beside} CPU-bound processes, load {load_before:.2f} before / "
          f"{load_after:.2f} after, "
          f"{platform.processor() or platform.machine()}")
    per = {name: [1e9 * t / samples for t in values] for name, values in times.items()}
    for name, values in per.items():
        check = f"  (states within {checks[name]:.1e} of the range)" if name in checks else ""
        print(f"  {name:9s} {statistics.median(values):9.1f} ns/step (range {min(values):.1f}-{max(values):.1f}){check}")
    for c in contenders:
        if c["pair"]:
            ratios = [a / b for a, b in zip(per[c["pair"]], per[c["name"]])]
            print(f"  {c['pair']} / {c['name']}: median {statistics.median(ratios):.2f} "
                  f"(range {min(ratios):.2f}-{max(ratios):.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
