#!/usr/bin/env python3
"""The AP2 air-data calibration run online by generated C: the recursive least squares of the
linear parameters (the airspeed scale and bias, the wind) at the batch estimate's angle
parameters, written by ``casest.export.export_rls_c``, compiled, and fed the record sample by
sample by a small C driver that reads a CSV file; its estimates converge to the batch estimate.

    python3 scripts/examples/ampyx_online_c.py [--out DIR]

The batch two-stage estimate on windows s1 + s2 (the worked example's) gives the angle
parameters (xi2, held) and the noise variances (the weights); Python's RecursiveLeastSquares
takes the first samples until its information has full rank, and the C code continues from
there over s1 + s2. At the last sample the C estimate is the weighted least squares of those
samples at that xi2, the batch estimate's own xi1. Writes ``ampyx_online_rls.png`` and the C
files to DIR (default: a new folder ``casest_online`` in the working directory; the docs' figure:
``--out docs/figures``, the C files then go to a temporary folder). Needs a C compiler and
matplotlib.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402
from casest.recursive import RecursiveLeastSquares  # noqa: E402
from casest.export import export_rls_c

WINDOW = (0.0, 32.8)  # s1 + s2 of the worked example

DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "ap2_rls.h"
/* one CSV line: the signals, then the outputs */
static int parse(char *line, double *v, int n) {
  char *p = line, *end;
  for (int j = 0; j < n; ++j) { v[j] = strtod(p, &end); if (end == p) return 0; p = end + (*end == ','); }
  return 1;
}
int main(int argc, char **argv) {
  ap2_rls_t f;
  enum { Q = AP2_RLS_N_LINEAR, N2 = AP2_RLS_N_NONLINEAR, NX = AP2_RLS_N_SIGNALS, NY = AP2_RLS_N_OUTPUTS };
  double start[Q + Q * Q + N2 + NY], row[NX + NY];
  char line[4096];
  FILE *in = fopen(argv[1], "r");
  if (!in || !fgets(line, sizeof line, in) || !parse(line, start, Q + Q * Q + N2 + NY)) return 3;
  if (ap2_rls_init(&f, start, start + Q, start + Q + Q * Q, start + Q + Q * Q + N2) != AP2_RLS_OK) return 5;
  while (fgets(line, sizeof line, in)) {
    if (!parse(line, row, NX + NY)) return 3;
    if (ap2_rls_step(&f, row, row + NX, NULL)) return 4;
    for (int j = 0; j < Q; ++j) printf("%.17g%c", ap2_rls_estimate(&f)[j], j + 1 < Q ? ',' : '\n');
  }
  fclose(in);
  return 0;
}
"""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=os.path.join(os.getcwd(), "casest_online"), help="folder of the figure")
    args = parser.parse_args(argv)
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise SystemExit("no C compiler found (cc or gcc)")
    module = casest.load_model_file("ampyx_air_data")
    model, data = module.model(), module.load(WINDOW)
    est = casest.estimate(model, data, sweep_settings=module.SWEEP_SETTINGS)
    partition = casest.separate(model)
    xi2 = np.array([est.values[n] for n in partition.nonlinear])
    rls = RecursiveLeastSquares(model, partition, xi2, weights=est.R, inversion="measurements")
    k = 0
    while rls.info_inv is None:  # Python's batch phase: until the information has full rank
        rls.update(data.signals[k], data.outputs[k])
        k += 1
    os.makedirs(args.out, exist_ok=True)
    folder = args.out if not args.out.rstrip("/").endswith("docs/figures") else tempfile.mkdtemp(prefix="ap2_c_")
    paths = export_rls_c(model, os.path.join(folder, "ap2_rls_c"), name="ap2_rls", partition=partition)
    driver, exe, csv = (os.path.join(folder, f) for f in ("ap2_driver.c", "ap2_driver", "ap2_record.csv"))
    with open(driver, "w") as fh:
        fh.write(DRIVER)
    subprocess.run([cc, "-std=c99", "-O2", f"-I{os.path.dirname(paths['header'])}", driver, paths["source"], "-lm",
                    "-o", exe], check=True)
    start = [*rls.p, *rls.info_inv.reshape(-1, order="F"), *xi2, *est.R]
    rows = np.hstack([data.signals[k:], data.outputs[k:]])
    with open(csv, "w") as fh:
        fh.write(",".join(repr(float(v)) for v in start) + "\n")
        fh.writelines(",".join(repr(float(v)) for v in row) + "\n" for row in rows)
    run = subprocess.run([exe, csv], capture_output=True, text=True, check=True)
    online = np.array([[float(v) for v in line.split(",")] for line in run.stdout.splitlines()])
    batch = np.array([est.values[n] for n in partition.linear])
    std = np.array([est.stds[n] for n in partition.linear])
    print(f"C recursive least squares over samples {k}-{data.n_samples - 1} of s1 + s2 ({len(online)} steps)")
    for name, value, b, s in zip(partition.linear, online[-1], batch, std):
        print(f"  {name:8s} online {value:+.6f}   batch {b:+.6f}   difference {abs(value - b) / s:.2e} std")
    _figure(data.extra["t"][k:], online, batch, std, partition.linear, os.path.join(args.out, "ampyx_online_rls.png"))
    return 0


def _figure(t, online, batch, std, names, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(names), 1, sharex=True, figsize=(7, 1.5 * len(names) + 0.6))
    for ax, series, b, s, name in zip(axes, online.T, batch, std, names):
        ax.plot(t, series, lw=0.9, label="generated C, online")
        ax.axhspan(b - s, b + s, color="C1", alpha=0.25, label="batch estimate +- 1 std")
        ax.axhline(b, color="C1", lw=0.8)
        ax.set_ylabel(name, fontsize=8)
        ax.set_ylim(b - 20 * s, b + 20 * s)
    axes[0].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("time (s)")
    fig.suptitle("AP2 air data: recursive least squares in generated C against the batch estimate", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print("wrote", path)


if __name__ == "__main__":
    sys.exit(main())
