"""The C drivers and the record the tests of casest's C exports share (tests/test_export_c*.py and
scripts/examples/c_export_on_arm.py): a driver reads a filter's start and constants and a record
on standard input and prints each sample's state, covariance and innovation.

Truth: the short-period model file's record (models/short_period.py, seed 3) with a missing
output at every 7th sample.
"""

import numpy as np

import casest

__all__ = ["DRIVER", "FLOAT_DRIVER", "short_period_case"]

DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "NAME.h"
#define N_D (2 * NAME_UPPER_N_OUTPUTS + NAME_UPPER_N_INPUTS + 2 * NAME_UPPER_N_STEP_INPUTS + 1)
static double x0[NAME_UPPER_N_STATES], P0[NAME_UPPER_N_STATES * NAME_UPPER_N_STATES], theta[NAME_UPPER_N_PARAMETERS],
  Qc[NAME_UPPER_N_STATES * NAME_UPPER_N_STATES], noise[NAME_UPPER_N_INPUTS + 1],
  R[NAME_UPPER_N_OUTPUTS * NAME_UPPER_N_OUTPUTS], d[N_D];
static void read(double *v, int n) { for (int i = 0; i < n; ++i) if (scanf("%lf", &v[i]) != 1) exit(3); }
int main(int argc, char **argv) {
  static NAME_t f;
  int N, k, j, measured[NAME_UPPER_N_OUTPUTS];
  const int n = NAME_UPPER_N_STATES, ny = NAME_UPPER_N_OUTPUTS, nu = NAME_UPPER_N_INPUTS, nuk = NAME_UPPER_N_STEP_INPUTS;
  if (scanf("%d", &N) != 1) return 3;
  read(x0, n); read(P0, n * n); read(theta, NAME_UPPER_N_PARAMETERS); read(Qc, n * n); read(noise, nu); read(R, ny * ny);
  if (NAME_init(&f, x0, P0, theta, Qc, noise, R, argc > 1 ? atof(argv[1]) : 0.0) != NAME_UPPER_OK) return 4;
  for (k = 0; k < N; ++k) {
    read(d, N_D);
    for (j = 0; j < ny; ++j) measured[j] = d[ny + j] != 0.0;
    int flag = NAME_step(&f, d, measured, d + 2 * ny, d + 2 * ny + nu, d + 2 * ny + nu + nuk, d[N_D - 1]);
    if (flag) return 10 + flag;
    const double *x = NAME_state(&f), *P = NAME_covariance(&f), *e = NAME_innovation(&f);
    for (j = 0; j < n; ++j) printf("%.17g ", x[j]);
    for (j = 0; j < n * n; ++j) printf("%.17g ", P[j]);
    for (j = 0; j < ny; ++j) printf("%.17g ", e[j]);
    printf("\n");
  }
  fprintf(stderr, "%llu %llu\n", f.rejected, f.failed);
  return 0;
}
"""


FLOAT_DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "fl.h"
#define N_D (2 * FL_N_OUTPUTS + FL_N_INPUTS + 2 * FL_N_STEP_INPUTS + 1)
static fl_real x0[FL_N_STATES], P0[FL_N_STATES * FL_N_STATES], theta[FL_N_PARAMETERS],
  Qc[FL_N_STATES * FL_N_STATES], noise[FL_N_INPUTS + 1], R[FL_N_OUTPUTS * FL_N_OUTPUTS], d[N_D];
static void read(fl_real *v, int n) { double t; for (int i = 0; i < n; ++i) { if (scanf("%lf", &t) != 1) exit(3); v[i] = (fl_real)t; } }
int main(void) {
  fl_t f;
  int N, k, j;
  const int n = FL_N_STATES, ny = FL_N_OUTPUTS, nu = FL_N_INPUTS, nuk = FL_N_STEP_INPUTS;
  if (scanf("%d", &N) != 1) return 3;
  read(x0, n); read(P0, n * n); read(theta, FL_N_PARAMETERS); read(Qc, n * n); read(noise, nu); read(R, ny * ny);
  if (fl_init(&f, x0, P0, theta, Qc, noise, R, 0.0f) != FL_OK) return 4;
  for (k = 0; k < N; ++k) {
    read(d, N_D);
    int flag = fl_step(&f, d, NULL, d + 2 * ny, d + 2 * ny + nu, d + 2 * ny + nu + nuk, d[N_D - 1]);
    if (flag) { printf("flag %d %d\n", flag, k); return 0; }
    for (j = 0; j < n; ++j) printf("%.9g ", (double)fl_state(&f)[j]);
    for (j = 0; j < n * n; ++j) printf("%.9g ", (double)fl_covariance(&f)[j]);
    printf("\n");
  }
  return 0;
}
"""


def short_period_case():
    """``(model file, model, record, R)``: the short-period record (seed 3) with the second output
    missing at every 7th sample, and the model file's noise variances."""
    m = casest.load_model_file("short_period")
    model = m.model()
    data = m.simulate(seed=3)
    outputs = data.outputs.copy()
    outputs[::7, 1] = np.nan  # a missing channel every 7th sample
    data = casest.Dataset.from_arrays(model, data.signals, outputs, missing="allow")
    R = [m.NOISE_STD[n] ** 2 for n in model.output_names]
    return m, model, data, R
