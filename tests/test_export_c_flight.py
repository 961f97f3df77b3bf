"""The flight semantics of casest's exported filters: a NaN, an infinite or an outlier measurement
costs one update and the rest of the record equals the filter that skipped that sample; a
non-finite input or dt keeps the state; init checks each argument. Compiled with the system
compiler and run over a record by a small C driver; skipped, with the reason, where no C compiler
exists.

Truth: casest's own filter (its compiled pass, the same step) over the short-period record
(models/short_period.py, seed 3) with the bad samples missing.
"""

import shutil
import subprocess

import numpy as np
import pytest

import casest
from casest.export.filter_c import export_c
from casest.filters.compiled_passes import record_columns
from c_export_drivers import DRIVER, short_period_case

CC = shutil.which("cc") or shutil.which("gcc")


@pytest.fixture(scope="module")
def case():
    return short_period_case()


def _flagging_driver(tmp_path, case, kind="ekf"):
    """The short-period filter (EKF, IEKF or UKF) exported as ``fl`` and the driver that prints each
    step's flag before its state, and the counters on standard error: ``(filter, executable)``."""
    m, model, _, R = case
    arguments = (model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-4)
    flt = casest.UnscentedKalmanFilter(*arguments, x0=np.zeros(2)) if kind == "ukf" else \
        casest.ExtendedKalmanFilter(*arguments, x0=np.zeros(2), iterated=kind == "iekf")
    paths = export_c(flt, tmp_path / "out", name="fl")
    driver = tmp_path / "driver.c"
    driver.write_text(DRIVER.replace("if (flag) return 10 + flag;", 'printf("%d ", flag);')
                      .replace("NAME_UPPER", "FL").replace("NAME", "fl"))
    exe = tmp_path / "driver"
    subprocess.run([CC, "-std=c99", "-O2", f"-I{tmp_path / 'out'}", str(driver), paths["source"], "-lm", "-o", str(exe)],
                   check=True)
    return flt, exe


def _run_flagging_driver(flt, exe, lines, gate: float = 0.0):
    """The driver run over the record's lines: per sample, the flag then the state, covariance,
    innovation; with ``gate``, also the counters ``(rejected, failed)``."""
    noise = getattr(flt, "input_noise", np.zeros(flt.model.n_inputs if hasattr(flt.model, "n_inputs") else 1))
    numbers = [*flt.x0, *flt.P0.reshape(-1, order="F"), *flt.theta, *flt.Qc.reshape(-1, order="F"),
               *noise, *flt.R.reshape(-1, order="F")]
    run = subprocess.run([str(exe), repr(gate)], input=f"{len(lines)} " + " ".join(repr(float(v)) for v in numbers)
                         + "\n" + "\n".join(lines), capture_output=True, text=True, check=True)
    out = np.array([[float(v) for v in line.split()] for line in run.stdout.splitlines()])
    return (out, tuple(int(v) for v in run.stderr.split())) if gate else out


def test_a_corrupt_sample_costs_one_update_not_the_filter(tmp_path, case):
    """Truth: the filter that never saw sample 50 (all its outputs missing). The C filter given a
    corrupt value (1e300, marked measured) at sample 50 returns 2 there, drops that sample's
    measurements, and goes on: every later state equals the truth's (1e-10); a non-finite dt at
    sample 60 returns 3 and keeps the state."""
    if CC is None:
        pytest.skip("no C compiler on this machine")
    _, model, data, _ = case
    ekf, exe = _flagging_driver(tmp_path, case)
    D, _ = record_columns(model, data)
    ny = model.n_outputs
    D = D[:70].copy()
    D[50, :ny], D[50, ny:2 * ny] = 1e300, 1.0
    lines = [" ".join(repr(float(v)) for v in row) for row in D]
    dt_line = D[60].copy()
    dt_line[-1] = np.nan
    lines[60] = " ".join(repr(float(v)) for v in dt_line)
    out = _run_flagging_driver(ekf, exe, lines)
    flags = out[:, 0].astype(int)
    assert flags[50] == 2 and flags[60] == 3 and not np.any(np.delete(flags, [50, 60]))
    outputs = data.outputs[:70].copy()
    outputs[50] = np.nan
    truth = ekf.filter(casest.Dataset.from_arrays(model, data.signals[:70], outputs, missing="allow"), compiled=True)
    np.testing.assert_allclose(out[51:60, 1:3], truth.x_filtered[51:60], rtol=1e-10, atol=1e-12)


def test_a_nan_or_infinite_measurement_costs_one_update_and_an_infinite_input_is_flagged_at_its_step(tmp_path, case):
    """Truth: the filter that never saw samples 30 and 40 (their outputs missing). An infinite and a
    NaN measurement marked measured at samples 30 and 40 return 8 (FL_NON_FINITE_MEASUREMENT) there,
    and every state up to sample 44 equals the truth's (1e-10); an infinite input at sample 45
    returns 3 at that step."""
    if CC is None:
        pytest.skip("no C compiler on this machine")
    _, model, data, _ = case
    ekf, exe = _flagging_driver(tmp_path, case)
    D, _ = record_columns(model, data)
    ny = model.n_outputs
    D = D[:60].copy()
    D[30, 0], D[30, ny] = np.inf, 1.0
    D[40, 1], D[40, ny + 1] = np.nan, 1.0
    D[45, 2 * ny] = np.inf  # the elevator input
    lines = [" ".join(repr(float(v)) for v in row) for row in D]
    out = _run_flagging_driver(ekf, exe, lines)
    flags = out[:, 0].astype(int)
    assert flags[30] == 8 and flags[40] == 8 and flags[45] == 3 and not np.any(np.delete(flags, [30, 40, 45]))
    outputs = data.outputs[:60].copy()
    outputs[[30, 40]] = np.nan
    truth = ekf.filter(casest.Dataset.from_arrays(model, data.signals[:60], outputs, missing="allow"), compiled=True)
    np.testing.assert_allclose(out[:45, 1:3], truth.x_filtered[:45], rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kind", ["ekf", "iekf", "ukf"])
def test_a_bad_sample_leaves_the_last_good_state_and_the_rest_equals_the_filter_that_skipped_it(tmp_path, case, kind):
    """Truth: casest's filter (its compiled pass, the same step) over the record with samples 20,
    35 and 50 missing. The C filter with an innovation gate of 30 (chi-square, 3 channels: about
    1e-6 for a good sample) is given a NaN (sample 20) and an infinite (35) measurement marked
    measured, and at 50 an outlier 40 noise std off on the first channel; it returns 8, 8, 7 there
    and 0 elsewhere, every state equals the truth's to 1e-12 of the states' range. A NaN dt at
    sample 70 returns 3 and leaves the state of sample 69. The struct counts 1 rejected step and 3
    failed ones (the two measurements and the dt)."""
    if CC is None:
        pytest.skip("no C compiler on this machine")
    m, model, data, R = case
    flt, exe = _flagging_driver(tmp_path, case, kind)
    D, _ = record_columns(model, data)
    ny = model.n_outputs
    D = D[:80].copy()
    D[20, 0], D[20, ny] = np.nan, 1.0
    D[35, 1], D[35, ny + 1] = -np.inf, 1.0
    D[50, 0] += 40 * m.NOISE_STD[model.output_names[0]]
    D[70, -1] = np.nan
    lines = [" ".join(repr(float(v)) for v in row) for row in D]
    out, (rejected, failed) = _run_flagging_driver(flt, exe, lines, gate=30.0)
    flags = out[:, 0].astype(int)
    assert list(flags[[20, 35, 50, 70]]) == [8, 8, 7, 3] and not np.any(np.delete(flags, [20, 35, 50, 70]))
    assert (rejected, failed) == (1, 3)
    outputs = data.outputs[:80].copy()
    outputs[[20, 35, 50]] = np.nan
    truth = flt.filter(casest.Dataset.from_arrays(model, data.signals[:80], outputs, missing="allow"), compiled=True)
    span = np.abs(truth.x_filtered).max(axis=0)
    assert np.all(np.abs(out[:70, 1:3] - truth.x_filtered[:70]) <= 1e-12 * span)
    np.testing.assert_array_equal(out[70, 1:], out[69, 1:])  # the state, P and innovation of sample 69 kept


INIT_DRIVER = r"""
#include <stdio.h>
#include <math.h>
#include "fl.h"
#define CASE(call) printf("%d ", (int)(call))
int main(void) {
  static fl_t f;
  double x0[2] = {0.1, -0.2}, P0[4] = {1e-4, 0, 0, 1e-4}, theta[FL_N_PARAMETERS] = {0}, Qc[4] = {0, 0, 0, 1e-4};
  double R[9] = {1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-2}, noise[1] = {1e-6};
  double neg_R[9] = {-1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-2}, asym_R[9] = {1e-4, 1e-5, 0, 0, 1e-4, 0, 0, 0, 1e-2};
  double zero_R[9] = {0}, bad_P0[4] = {1e-4, 2e-4, 2e-4, 1e-4}, asym_P0[4] = {1e-4, 1e-5, 0, 1e-4};
  double neg_Qc[4] = {0, 0, 0, -1e-4}, zero_P0[4] = {0, 0, 0, 0}, nan_x0[2] = {NAN, 0}, inf_theta[FL_N_PARAMETERS] = {0};
  double nan_noise[1] = {NAN};
  inf_theta[2] = INFINITY;
  CASE(fl_init(NULL, x0, P0, theta, Qc, NULL, R, 0)); CASE(fl_init(&f, NULL, P0, theta, Qc, NULL, R, 0));
  CASE(fl_init(&f, x0, P0, NULL, Qc, NULL, R, 0)); CASE(fl_init(&f, nan_x0, P0, theta, Qc, NULL, R, 0));
  CASE(fl_init(&f, x0, P0, inf_theta, Qc, NULL, R, 0)); CASE(fl_init(&f, x0, P0, theta, Qc, nan_noise, R, 0));
  CASE(fl_init(&f, x0, P0, theta, Qc, NULL, R, -1)); CASE(fl_init(&f, x0, P0, theta, Qc, NULL, R, NAN));
  CASE(fl_init(&f, x0, P0, theta, Qc, NULL, neg_R, 0)); CASE(fl_init(&f, x0, P0, theta, Qc, NULL, asym_R, 0));
  CASE(fl_init(&f, x0, P0, theta, Qc, NULL, zero_R, 0)); CASE(fl_init(&f, x0, bad_P0, theta, Qc, NULL, R, 0));
  CASE(fl_init(&f, x0, asym_P0, theta, Qc, NULL, R, 0)); CASE(fl_init(&f, x0, P0, theta, neg_Qc, NULL, R, 0));
  CASE(fl_init(&f, x0, zero_P0, theta, Qc, NULL, R, 0)); CASE(fl_init(&f, x0, P0, theta, Qc, noise, R, 16.27));
  printf("\n%.17g %.17g %.17g\n", fl_state(&f)[0], fl_state(&f)[1], fl_covariance(&f)[3]);
  printf("%zu %u %u\n", sizeof(fl_t), (unsigned)FL_STRUCT_BYTES, (unsigned)FL_WORK_BYTES);
  return 0;
}
"""


def test_init_checks_every_argument_and_the_state_starts_at_x0(tmp_path, case):
    """Truth by construction: a NULL filter, start or theta, a NaN start, an infinite parameter, a
    NaN input noise, a negative or NaN gate return 4 (FL_INVALID_ARGUMENT); a negative, asymmetric
    or zero R 5; a P0 with a negative eigenvalue (1e-4 -+ 2e-4), an asymmetric P0 or a negative
    Qc 6; a zero P0 (a known start) and the right arguments 0. After init the state is x0 and the
    covariance P0; the header's FL_STRUCT_BYTES is the compiler's sizeof and FL_WORK_BYTES less."""
    if CC is None:
        pytest.skip("no C compiler on this machine")
    m, model, data, R = case
    ekf = casest.ExtendedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-4)
    paths = export_c(ekf, tmp_path / "out", name="fl")
    driver = tmp_path / "init.c"
    driver.write_text(INIT_DRIVER)
    exe = tmp_path / "init"
    subprocess.run([CC, "-std=c99", "-O2", f"-I{tmp_path / 'out'}", str(driver), paths["source"], "-lm", "-o", str(exe)],
                   check=True)
    flags, state, sizes = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout.splitlines()
    assert flags.split() == ["4"] * 8 + ["5"] * 3 + ["6"] * 3 + ["0", "0"]
    assert [float(v) for v in state.split()] == [0.1, -0.2, 1e-4]
    size, stated, work = (int(v) for v in sizes.split())
    assert size == stated and 0 < work < size


RLS_FLAG_DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include <math.h>
#include "rls.h"
int main(void) {
  static rls_t f;
  int N, k, j, measured[RLS_N_OUTPUTS], q = RLS_N_LINEAR, n2 = RLS_N_NONLINEAR, nx = RLS_N_SIGNALS, ny = RLS_N_OUTPUTS;
  double p[RLS_N_LINEAR], P[RLS_N_LINEAR * RLS_N_LINEAR], xi2[RLS_N_NONLINEAR + 1], w[RLS_N_OUTPUTS],
    x[RLS_N_SIGNALS], z[RLS_N_OUTPUTS], bad_w[RLS_N_OUTPUTS], bad_P[RLS_N_LINEAR * RLS_N_LINEAR];
  if (scanf("%d", &N) != 1) return 3;
  for (j = 0; j < q; ++j) if (scanf("%lf", &p[j]) != 1) return 3;
  for (j = 0; j < q * q; ++j) if (scanf("%lf", &P[j]) != 1) return 3;
  for (j = 0; j < n2; ++j) if (scanf("%lf", &xi2[j]) != 1) return 3;
  for (j = 0; j < ny; ++j) { if (scanf("%lf", &w[j]) != 1) return 3; bad_w[j] = -w[j]; }
  for (j = 0; j < q * q; ++j) bad_P[j] = -P[j];
  printf("%d %d %d %d\n", (int)rls_init(&f, NULL, P, xi2, w), (int)rls_init(&f, p, P, xi2, bad_w),
         (int)rls_init(&f, p, bad_P, xi2, w), (int)rls_init(&f, p, P, xi2, w));
  for (k = 0; k < N; ++k) {
    for (j = 0; j < nx; ++j) if (scanf("%lf", &x[j]) != 1) return 3;
    for (j = 0; j < ny; ++j) { if (scanf("%lf", &z[j]) != 1) return 3; measured[j] = 1; }
    printf("%d ", (int)rls_step(&f, x, z, measured));
    for (j = 0; j < q; ++j) printf("%.17g ", rls_estimate(&f)[j]);
    printf("\n");
  }
  printf("%llu\n", f.failed);
  return 0;
}
"""


def test_the_recursive_least_squares_skips_a_bad_sample_and_init_checks_its_arguments(tmp_path):
    """Truth: casest's RecursiveLeastSquares (paper scalar example 2 at its true xi2, seed 5, started
    after 10 samples) over the record without samples 40 and 60. The C estimator given a NaN
    measurement marked measured at 40 returns 8 (RLS_NON_FINITE_MEASUREMENT) and an infinite signal
    at 60 returns 3 (RLS_NON_FINITE_INPUT), keeps the estimate at both, and equals the truth at every
    sample (1e-10); it counts 2 failed steps. Init: a NULL start 4, negative variances 5, a
    negative covariance 6, the right arguments 0."""
    if CC is None:
        pytest.skip("no C compiler on this machine")
    from casest.recursive import RecursiveLeastSquares
    from casest.export.rls_c import export_rls_c

    s2 = casest.load_model_file("scalar2")
    model, data = s2.model(), s2.simulate(seed=5, n=120)
    partition = casest.separate(model)
    xi2 = [s2.TRUTH[n] for n in partition.nonlinear]
    rls = RecursiveLeastSquares(model, partition, xi2, weights=[0.09], inversion="measurements")
    for k in range(10):
        rls.update(data.signals[k], data.outputs[k])
    start = [*rls.p, *rls.info_inv.reshape(-1, order="F"), *xi2, 0.09]
    truth = []
    for k in range(10, data.n_samples):
        if k not in (40, 60):
            rls.update(data.signals[k], data.outputs[k])
        truth.append(rls.p.copy())
    paths = export_rls_c(model, tmp_path / "out", name="rls", partition=partition)
    (tmp_path / "driver.c").write_text(RLS_FLAG_DRIVER)
    exe = tmp_path / "driver"
    subprocess.run([CC, "-std=c99", "-O2", f"-I{tmp_path / 'out'}", str(tmp_path / "driver.c"), paths["source"], "-lm",
                    "-o", str(exe)], check=True)
    signals, outputs = data.signals.copy(), data.outputs.copy()
    outputs[40, 0], signals[60, 0] = np.nan, np.inf
    rows = [" ".join(repr(float(v)) for v in [*signals[k], *outputs[k]]) for k in range(10, data.n_samples)]
    lines = subprocess.run([str(exe)], input=f"{len(rows)} " + " ".join(repr(float(v)) for v in start) + "\n"
                           + "\n".join(rows), capture_output=True, text=True, check=True).stdout.splitlines()
    assert lines[0].split() == ["4", "5", "6", "0"]
    assert int(lines[-1]) == 2
    out = np.array([[float(v) for v in line.split()] for line in lines[1:-1]])
    flags = out[:, 0].astype(int)
    assert flags[40 - 10] == 8 and flags[60 - 10] == 3 and not np.any(np.delete(flags, [30, 50]))
    np.testing.assert_allclose(out[:, 1:], np.array(truth), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_bad_samples_at_random_places_each_cost_one_update(tmp_path, case, kind):
    """Drawn with seed 20261202 (not used to tune anything): 12 bad samples at random places of a
    400-sample record, each a NaN, an infinite or a 40-std outlier on a random channel, with the
    gate at 30. Each returns its code (8, 8, 7), every other sample 0, and every state equals
    casest's filter over the record with those samples missing, to 1e-12 of the states' range."""
    if CC is None:
        pytest.skip("no C compiler on this machine")
    m, model, data, _ = case
    flt, exe = _flagging_driver(tmp_path, case, kind)
    rng = np.random.default_rng(20261202)
    D, _ = record_columns(model, data)
    ny, N = model.n_outputs, 400
    D = D[:N].copy()
    bad = np.sort(rng.choice(np.arange(5, N), size=12, replace=False))
    kinds = rng.integers(0, 3, size=12)
    expected = np.zeros(N, dtype=int)
    for k, what in zip(bad, kinds):
        channel = int(rng.integers(0, ny))
        if not D[k, ny + channel]:  # a channel missing in the record (every 7th sample): make it measured
            D[k, ny + channel] = 1.0
            D[k, channel] = data.outputs[k - 1, channel]
        D[k, channel] = (np.nan, np.inf, D[k, channel] + 40 * m.NOISE_STD[model.output_names[channel]])[what]
        expected[k] = (8, 8, 7)[what]
    lines = [" ".join(repr(float(v)) for v in row) for row in D]
    out, (rejected, failed) = _run_flagging_driver(flt, exe, lines, gate=30.0)
    np.testing.assert_array_equal(out[:, 0].astype(int), expected)
    assert (rejected, failed) == (int(np.sum(expected == 7)), int(np.sum(expected == 8)))
    outputs = data.outputs[:N].copy()
    outputs[bad] = np.nan
    truth = flt.filter(casest.Dataset.from_arrays(model, data.signals[:N], outputs, missing="allow"), compiled=True)
    span = np.abs(truth.x_filtered).max(axis=0)
    assert np.all(np.abs(out[:, 1:3] - truth.x_filtered) <= 1e-12 * span)
