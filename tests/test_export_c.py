"""The EKF, IEKF and UKF generated as C (casest.export_c): compiled with the system compiler and run
over a record by a small C driver, every sample's x(k|k), P(k|k) and innovation equal casest's
compiled filter pass (the same step: 1e-12) and its step-by-step NumPy filter (1e-9); the
object file references no heap allocation (only libm). Skipped, with the reason, where no C
compiler exists.

Truth: the short-period model file's record (models/short_period.py, seed 3) with a missing
output at every 7th sample, filtered at the true parameters.
"""

import shutil
import subprocess

import numpy as np
import pytest

import casest
from casest.export.filter_c import export_c
from casest.filters.compiled_passes import record_columns

CC = shutil.which("cc") or shutil.which("gcc")

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


@pytest.fixture(scope="module")
def case():
    m = casest.load_model_file("short_period")
    model = m.model()
    data = m.simulate(seed=3)
    outputs = data.outputs.copy()
    outputs[::7, 1] = np.nan  # a missing channel every 7th sample
    data = casest.Dataset.from_arrays(model, data.signals, outputs, missing="allow")
    R = [m.NOISE_STD[n] ** 2 for n in model.output_names]
    return m, model, data, R


@pytest.mark.parametrize("kind", ["ekf", "iekf", "ukf"])
def test_the_generated_filter_equals_casests(tmp_path, case, kind):
    if CC is None:
        pytest.skip("no C compiler on this machine")
    m, model, data, R = case
    arguments = (model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-4)
    ekf = casest.UnscentedKalmanFilter(*arguments, x0=np.zeros(2)) if kind == "ukf" else \
        casest.ExtendedKalmanFilter(*arguments, x0=np.zeros(2), iterated=kind == "iekf")
    paths = export_c(ekf, tmp_path / "out", name="fl")
    obj = tmp_path / "fl.o"
    subprocess.run([CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-c", paths["source"], "-o", str(obj)], check=True)
    undefined = subprocess.run(["nm", "-u", str(obj)], capture_output=True, text=True).stdout.split()
    heap = {"malloc", "calloc", "realloc", "free"} & {u.lstrip("_").split("@")[0] for u in undefined if u != "U"}
    assert not heap, undefined
    driver = tmp_path / "driver.c"
    driver.write_text(DRIVER.replace("NAME_UPPER", "FL").replace("NAME", "fl"))
    exe = tmp_path / "driver"
    subprocess.run([CC, "-std=c99", "-O2", f"-I{tmp_path / 'out'}", str(driver), paths["source"], "-lm", "-o", str(exe)],
                   check=True)
    D, _ = record_columns(model, data)
    noise = getattr(ekf, "input_noise", np.zeros(len(model.inputs)))  # the UKF takes none (read and unused)
    numbers = [data.n_samples, *ekf.x0, *ekf.P0.reshape(-1, order="F"), *ekf.theta, *ekf.Qc.reshape(-1, order="F"),
               *noise, *ekf.R.reshape(-1, order="F")]
    text = " ".join(repr(float(v)) for v in numbers[1:])
    run = subprocess.run([str(exe)], input=f"{data.n_samples} {text}\n" + "\n".join(" ".join(repr(float(v)) for v in row)
                                                                                      for row in D),
                         capture_output=True, text=True, check=True)
    out = np.array([[float(v) for v in line.split()] for line in run.stdout.splitlines()])
    n, ny = 2, model.n_outputs
    x_c, P_c, e_c = out[:, :n], out[:, n:n + n * n].reshape(-1, n, n, order="F"), out[:, n + n * n:]
    compiled = ekf.filter(data, compiled=True)
    np.testing.assert_allclose(x_c, compiled.x_filtered, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(P_c, compiled.P_filtered, rtol=1e-12, atol=1e-18)
    stepwise = ekf.filter(data, compiled=False)
    np.testing.assert_allclose(x_c, stepwise.x_filtered, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(P_c, stepwise.P_filtered, rtol=1e-9, atol=1e-15)
    seen = np.isfinite(stepwise.innovation)
    np.testing.assert_allclose(e_c[seen], stepwise.innovation[seen], rtol=1e-9, atol=1e-12)


def test_export_refuses_what_it_cannot_write(tmp_path, case):
    m, model, data, R = case
    with pytest.raises(casest.OptionError, match="export_c takes a casest.ExtendedKalmanFilter"):
        export_c(object(), tmp_path)
    ekf = casest.ExtendedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-4)
    with pytest.raises(casest.OptionError, match="name must be a C identifier"):
        export_c(ekf, tmp_path, name="my-filter")


@pytest.mark.parametrize("name, message", [("_Bool", "start with a letter"), ("__init", "start with a letter"),
                                           ("int", "C keyword"), ("math", "shadows the standard header <math.h>"),
                                           ("errno", "shadows the standard header"), ("a__b", "two underscores")])
def test_prefixes_c_or_casadi_cannot_take_are_refused(tmp_path, case, name, message):
    m, model, data, R = case
    ekf = casest.ExtendedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-4)
    with pytest.raises(casest.OptionError, match=message):
        export_c(ekf, tmp_path, name=name)
    assert not any(tmp_path.iterdir())


def test_an_export_never_replaces_what_casest_did_not_write(tmp_path, case):
    """Two exports into one folder keep both README sections; a user's README.md or NAME.c stops
    the export unless forced (then listed); a link in the folder is never written through."""
    m, model, data, R = case
    ekf = casest.ExtendedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-4)
    out = tmp_path / "out"
    export_c(ekf, out, name="first")
    export_c(casest.UnscentedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-4), out, name="second")
    readme = (out / "README.md").read_text()
    assert "# first" in readme and "# second" in readme
    again = export_c(ekf, out, name="first")  # its own files: replaced, the other section kept
    assert again.replaced == () and (out / "README.md").read_text().count("# second") == 1
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "README.md").write_text("my notes\n")
    with pytest.raises(casest.OptionError, match="casest did not write it"):
        export_c(ekf, mine, name="fl")
    assert (mine / "README.md").read_text() == "my notes\n" and not (mine / "fl.c").exists()
    (mine / "fl.c").write_text("int main(void) { return 0; }\n")
    with pytest.raises(casest.OptionError, match="fl.c' exists and casest did not write it"):
        export_c(ekf, mine, name="fl", force=False)
    forced = export_c(ekf, mine, name="fl", force=True)
    assert sorted(forced.replaced) == sorted([str(mine / "fl.c"), str(mine / "README.md")])
    linked = tmp_path / "linked"
    linked.mkdir()
    target = tmp_path / "precious.md"
    target.write_text("keep\n")
    (linked / "README.md").symlink_to(target)
    with pytest.raises(casest.OptionError, match="symbolic link"):
        export_c(ekf, linked, name="fl", force=True)
    assert target.read_text() == "keep\n"


def test_the_command_line_writes_the_files(tmp_path, capsys):
    from casest.apps.cli import main

    assert main(["export-c", "short_period", "--estimator", "iekf", "--out", str(tmp_path / "c")]) == 0
    written = sorted(p.name for p in (tmp_path / "c").iterdir())
    assert written == ["README.md", "casest_short_period_iekf.c", "casest_short_period_iekf.h"]
    assert main(["export-c", "scalar2", "--out", str(tmp_path / "s")]) == 2  # a static model: a user error
    assert "export-c writes the filters of a casest.DynamicModel" in capsys.readouterr().err


RLS_DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "rls.h"
int main(void) {
  rls_t f;
  int N, k, j, q = RLS_N_LINEAR, n2 = RLS_N_NONLINEAR, nx = RLS_N_SIGNALS, ny = RLS_N_OUTPUTS;
  double p[RLS_N_LINEAR], P[RLS_N_LINEAR * RLS_N_LINEAR], xi2[RLS_N_NONLINEAR + 1], w[RLS_N_OUTPUTS],
    x[RLS_N_SIGNALS], z[RLS_N_OUTPUTS];
  if (scanf("%d", &N) != 1) return 3;
  for (j = 0; j < q; ++j) if (scanf("%lf", &p[j]) != 1) return 3;
  for (j = 0; j < q * q; ++j) if (scanf("%lf", &P[j]) != 1) return 3;
  for (j = 0; j < n2; ++j) if (scanf("%lf", &xi2[j]) != 1) return 3;
  for (j = 0; j < ny; ++j) if (scanf("%lf", &w[j]) != 1) return 3;
  rls_init(&f, p, P, xi2, w);
  for (k = 0; k < N; ++k) {
    for (j = 0; j < nx; ++j) if (scanf("%lf", &x[j]) != 1) return 3;
    for (j = 0; j < ny; ++j) if (scanf("%lf", &z[j]) != 1) return 3;
    if (rls_step(&f, x, z, NULL)) return 11;
    for (j = 0; j < q; ++j) printf("%.17g ", rls_estimate(&f)[j]);
    printf("\n");
  }
  return 0;
}
"""


def test_the_generated_recursive_least_squares_equals_casests(tmp_path):
    """Paper scalar example 2 at its true xi2: the C recursive least squares, started from casest's
    RecursiveLeastSquares after its first 10 samples (the batch phase), equals it at every later
    sample (1e-10), Eq. 4.14 on both sides; no heap."""
    if CC is None:
        pytest.skip("no C compiler on this machine")
    from casest.recursive import RecursiveLeastSquares
    from casest.export.rls_c import export_rls_c

    s2 = casest.load_model_file("scalar2")
    model, data = s2.model(), s2.simulate(seed=5, n=300)
    partition = casest.separate(model)
    xi2 = [s2.TRUTH[n] for n in partition.nonlinear]
    rls = RecursiveLeastSquares(model, partition, xi2, weights=[0.09], inversion="measurements")
    for k in range(10):
        rls.update(data.signals[k], data.outputs[k])
    p0, P0 = rls.p.copy(), rls.info_inv.copy()
    paths = export_rls_c(model, tmp_path / "out", name="rls", partition=partition)
    obj = tmp_path / "rls.o"
    subprocess.run([CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-c", paths["source"], "-o", str(obj)], check=True)
    undefined = subprocess.run(["nm", "-u", str(obj)], capture_output=True, text=True).stdout.split()
    assert not {"malloc", "calloc", "realloc", "free"} & {u.split("@")[0] for u in undefined}
    driver = tmp_path / "driver.c"
    driver.write_text(RLS_DRIVER)
    exe = tmp_path / "driver"
    subprocess.run([CC, "-std=c99", "-O2", f"-I{tmp_path / 'out'}", str(driver), paths["source"], "-lm", "-o",
                    str(exe)], check=True)
    rows = [[float(v) for v in (*data.signals[k], *data.outputs[k])] for k in range(10, data.n_samples)]
    text = " ".join(repr(float(v)) for v in [*p0, *P0.reshape(-1, order="F"), *xi2, 0.09])
    run = subprocess.run([str(exe)], input=f"{len(rows)} {text}\n" + "\n".join(" ".join(map(repr, r)) for r in rows),
                         capture_output=True, text=True, check=True)
    c_estimates = np.array([[float(v) for v in line.split()] for line in run.stdout.splitlines()])
    python = np.array([rls.update(data.signals[k], data.outputs[k]).copy() for k in range(10, data.n_samples)])
    np.testing.assert_allclose(c_estimates, python, rtol=1e-10, atol=1e-13)


def test_the_command_line_writes_a_static_models_recursive_least_squares(tmp_path, capsys):
    from casest.apps.cli import main

    assert main(["export-c", "scalar2", "--estimator", "rls", "--out", str(tmp_path / "r")]) == 0
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == ["README.md", "casest_scalar2_rls.c",
                                                                   "casest_scalar2_rls.h"]
    assert main(["export-c", "short_period", "--estimator", "rls", "--out", str(tmp_path / "x")]) == 2
    assert "writes the recursive least squares of a static casest.Model" in capsys.readouterr().err


BATCH_DRIVER = r"""
#include <stdio.h>
#include "ts.h"
static double s[TS_N_SIGNALS * TS_N_SAMPLES], z[TS_N_OUTPUTS * TS_N_SAMPLES], theta[TS_N_PARAMETERS],
  R[TS_N_OUTPUTS], cov[TS_N_PARAMETERS * TS_N_PARAMETERS], success;
static ts_work_t work;
int main(void) {
  int j;
  for (j = 0; j < TS_N_SIGNALS * TS_N_SAMPLES; ++j) if (scanf("%lf", &s[j]) != 1) return 3;
  for (j = 0; j < TS_N_OUTPUTS * TS_N_SAMPLES; ++j) if (scanf("%lf", &z[j]) != 1) return 3;
  if (ts_estimate(&work, s, z, theta, R, cov, &success)) return 11;
  for (j = 0; j < TS_N_PARAMETERS; ++j) printf("%.17g ", theta[j]);
  for (j = 0; j < TS_N_OUTPUTS; ++j) printf("%.17g ", R[j]);
  for (j = 0; j < TS_N_PARAMETERS * TS_N_PARAMETERS; ++j) printf("%.17g ", cov[j]);
  printf("%.17g\n", success);
  return 0;
}
"""


def test_the_generated_two_stage_estimator_equals_its_graph_and_casests_optimum(tmp_path):
    """Paper scalar example 2 (N = 100, seed 0): the generated C of the two-stage graph Function
    (SQP stage 2) gives the graph Function's own numbers (1e-9) and casest.estimate's optimum
    (1e-6 relative); no heap."""
    if CC is None:
        pytest.skip("no C compiler on this machine")
    from casest.interop import two_stage_graph_function
    from casest.export.batch_c import export_two_stage_c

    s2 = casest.load_model_file("scalar2")
    model, data = s2.model(), s2.simulate(seed=0, n=100)
    settings = casest.SweepSettings(n_candidates=64)
    paths = export_two_stage_c(model, 100, tmp_path / "out", name="ts", sweep_settings=settings)
    obj = tmp_path / "ts.o"
    subprocess.run([CC, "-std=c99", "-O1", "-c", paths["source"], "-o", str(obj)], check=True)
    undefined = subprocess.run(["nm", "-u", str(obj)], capture_output=True, text=True).stdout.split()
    assert not {"malloc", "calloc", "realloc", "free"} & {u.split("@")[0] for u in undefined}
    driver = tmp_path / "driver.c"
    driver.write_text(BATCH_DRIVER)
    exe = tmp_path / "driver"
    subprocess.run([CC, "-std=c99", "-O1", f"-I{tmp_path / 'out'}", str(driver), str(obj), "-lm", "-o", str(exe)],
                   check=True)
    numbers = [*data.signals.reshape(-1), *data.outputs.reshape(-1)]  # row-major (N, k) = column-major (k, N)
    run = subprocess.run([str(exe)], input=" ".join(repr(float(v)) for v in numbers), capture_output=True, text=True,
                         check=True)
    out = np.array([float(v) for v in run.stdout.split()])
    n = model.n_parameters
    theta, R, cov, success = out[:n], out[n:n + 1], out[n + 1:n + 1 + n * n].reshape(n, n, order="F"), out[-1]
    graph = two_stage_graph_function(model, 100, settings, solver="sqpmethod")
    expected = [np.asarray(v) for v in graph(data.signals.T, data.outputs.T)]
    np.testing.assert_allclose(theta, expected[0].ravel(), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(cov, expected[2], rtol=1e-8, atol=1e-14)
    assert success == 1.0
    est = casest.estimate(model, data)
    np.testing.assert_allclose(theta, est.theta, rtol=1e-6)


#: the Monte-Carlo NEES check: runs, samples per run, the prior and the process noise it draws from
NEES_RUNS, NEES_SAMPLES, NEES_P0, NEES_QC = 50, 400, np.diag([1e-4, 4e-4]), np.diag([0.0, 1e-3])


def _stochastic_runs(m, model, R):
    """NEES_RUNS free responses of the short-period model (elevator at zero) from initial states drawn
    from N(0, NEES_P0), with white process noise of spectral density NEES_QC (discretised exactly by
    Van Loan's method) and measurement noise R: the filter's own assumptions, so that its NEES is
    chi-square with 2 degrees of freedom at every sample (seeds 0..NEES_RUNS-1)."""
    from casest.filters.smoothing import continuous_to_discrete

    th, dt = m.TRUTH, 1.0 / m.RATE
    A = np.array([[th["Z_alpha"], 1.0], [th["M_alpha"], th["M_q"]]])
    Phi, _, Qd = continuous_to_discrete(A, np.zeros((2, 1)), np.eye(2), NEES_QC, dt)
    H = np.array([[1.0, 0.0], [0.0, 1.0], [m.V0 * th["Z_alpha"], 0.0]])
    offset = np.array([th["b_alpha"], th["b_q"], 0.0])
    t = np.arange(NEES_SAMPLES) * dt
    for seed in range(NEES_RUNS):
        rng = np.random.default_rng([seed, 59])
        x = np.empty((NEES_SAMPLES, 2))
        x[0] = rng.multivariate_normal(np.zeros(2), NEES_P0)
        for k in range(1, NEES_SAMPLES):
            x[k] = Phi @ x[k - 1] + rng.multivariate_normal(np.zeros(2), Qd)
        z = x @ H.T + offset + rng.standard_normal((NEES_SAMPLES, 3)) * np.sqrt(R)
        yield x, model.dataset({"t": t, "delta_e": np.zeros_like(t), **{n: z[:, j] for j, n in enumerate(model.output_names)}})


def test_the_generated_ekfs_nees_is_consistent_and_casests(tmp_path, case):
    """Monte Carlo over NEES_RUNS records drawn from the filter's own model (analytic truth: random
    initial states, process and measurement noise of the stated covariances; seeds 0-49). At samples 1,
    10, 100 and the last, the sum over the runs of the generated EKF's normalised estimation error
    squared lies in the chi-square interval of 2 NEES_RUNS degrees of freedom that holds 99.9 % of a
    consistent filter's sums, and every sample's NEES equals casest's NumPy filter's (1e-8)."""
    from scipy.stats import chi2

    if CC is None:
        pytest.skip("no C compiler on this machine")
    m, model, _, R = case
    ekf = casest.ExtendedKalmanFilter(model, m.TRUTH, {"q": NEES_QC[1, 1]}, R, NEES_P0, x0=np.zeros(2))
    paths = export_c(ekf, tmp_path / "out", name="fl")
    driver = tmp_path / "driver.c"
    driver.write_text(DRIVER.replace("NAME_UPPER", "FL").replace("NAME", "fl"))
    exe = tmp_path / "driver"
    subprocess.run([CC, "-std=c99", "-O2", f"-I{tmp_path / 'out'}", str(driver), paths["source"], "-lm", "-o", str(exe)],
                   check=True)
    header = [*ekf.x0, *ekf.P0.reshape(-1, order="F"), *ekf.theta, *ekf.Qc.reshape(-1, order="F"), *ekf.input_noise,
              *ekf.R.reshape(-1, order="F")]
    nees_c, nees_py = [], []
    for x_true, data in _stochastic_runs(m, model, R):
        D, _ = record_columns(model, data)
        text = f"{data.n_samples} " + " ".join(repr(float(v)) for v in header) + "\n" + \
            "\n".join(" ".join(repr(float(v)) for v in row) for row in D)
        lines = subprocess.run([str(exe)], input=text, capture_output=True, text=True, check=True).stdout.splitlines()
        values = np.array([[float(v) for v in line.split()] for line in lines])
        result = ekf.filter(data, compiled=False)
        for xs, Ps, out in ((values[:, :2], values[:, 2:6].reshape(-1, 2, 2, order="F"), nees_c),
                            (result.x_filtered, result.P_filtered, nees_py)):
            errors = xs - x_true
            out.append([float(e @ np.linalg.solve(P, e)) for e, P in zip(errors, Ps)])
    nees_c, nees_py = np.array(nees_c), np.array(nees_py)
    np.testing.assert_allclose(nees_c, nees_py, rtol=1e-8)
    low, high = chi2.ppf([0.0005, 0.9995], 2 * NEES_RUNS)
    for k in (1, 10, 100, NEES_SAMPLES - 1):
        assert low <= nees_c[:, k].sum() <= high, (k, nees_c[:, k].sum(), low, high)


RML_DRIVER = r"""
#include <stdio.h>
#include "rml.h"
int main(void) {
  rml_t f;
  int N, k, j, n = RML_N_PARAMETERS, ny = RML_N_OUTPUTS, nx = RML_N_SIGNALS, m = n + ny;
  double theta[RML_N_PARAMETERS], R[RML_N_OUTPUTS], I[(RML_N_PARAMETERS + RML_N_OUTPUTS) * (RML_N_PARAMETERS + RML_N_OUTPUTS)],
    lam, r, x[RML_N_SIGNALS], z[RML_N_OUTPUTS];
  if (scanf("%d", &N) != 1) return 3;
  for (j = 0; j < n; ++j) if (scanf("%lf", &theta[j]) != 1) return 3;
  for (j = 0; j < ny; ++j) if (scanf("%lf", &R[j]) != 1) return 3;
  for (j = 0; j < m * m; ++j) if (scanf("%lf", &I[j]) != 1) return 3;
  if (scanf("%lf %lf", &lam, &r) != 2) return 3;
  rml_init(&f, theta, R, I, lam, r);
  for (k = 0; k < N; ++k) {
    for (j = 0; j < nx; ++j) if (scanf("%lf", &x[j]) != 1) return 3;
    for (j = 0; j < ny; ++j) if (scanf("%lf", &z[j]) != 1) return 3;
    if (rml_step(&f, x, z, NULL)) return 11;
    for (j = 0; j < n; ++j) printf("%.17g ", rml_estimate(&f)[j]);
    for (j = 0; j < ny; ++j) printf("%.17g ", rml_log_noise(&f)[j]);
    printf("\n");
  }
  return 0;
}
"""


def test_the_generated_recursive_ml_equals_casests(tmp_path):
    """Paper scalar example 2 (300 samples, seed 2) from the nominal values with forgetting
    (lambda(0) = 0.9, r = 0.99) and a start information of 10: the C recursive ML equals casest's
    RecursiveML, one sample at a time, in theta and ln R at every sample (1e-8); no heap."""
    if CC is None:
        pytest.skip("no C compiler on this machine")
    from casest.recursive import RecursiveML
    from casest.export.rml_c import export_rml_c

    s2 = casest.load_model_file("scalar2")
    model, data = s2.model(), s2.simulate(seed=2, n=300)
    # an information of 10 on [theta; ln R] to start: with the default 1e-6 the first steps solve
    # systems of condition ~1e6, where NumPy's LU and CasADi's QR differ at 1e-3
    rml = RecursiveML(model, model.nominal, [0.5], information0=np.full(5, 10.0), forgetting=0.9,
                      forgetting_rate=0.99)
    start = [*rml.theta, *rml.R, *rml.information.reshape(-1, order="F"), 0.9, 0.99]
    paths = export_rml_c(model, tmp_path / "out", name="rml")
    obj = tmp_path / "rml.o"
    subprocess.run([CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-c", paths["source"], "-o", str(obj)], check=True)
    undefined = subprocess.run(["nm", "-u", str(obj)], capture_output=True, text=True).stdout.split()
    assert not {"malloc", "calloc", "realloc", "free"} & {u.split("@")[0] for u in undefined}
    driver = tmp_path / "driver.c"
    driver.write_text(RML_DRIVER)
    exe = tmp_path / "driver"
    subprocess.run([CC, "-std=c99", "-O2", f"-I{tmp_path / 'out'}", str(driver), str(obj), "-lm", "-o", str(exe)],
                   check=True)
    rows = [[float(v) for v in (*data.signals[k], *data.outputs[k])] for k in range(data.n_samples)]
    text = f"{data.n_samples} " + " ".join(repr(float(v)) for v in start) + "\n" + \
        "\n".join(" ".join(map(repr, r)) for r in rows)
    run = subprocess.run([str(exe)], input=text, capture_output=True, text=True, check=True)
    c_rows = np.array([[float(v) for v in line.split()] for line in run.stdout.splitlines()])
    python = []
    for k in range(data.n_samples):
        rml.update(data.signals[k:k + 1], data.outputs[k:k + 1])
        python.append([*rml.theta, *rml.rho])
    np.testing.assert_allclose(c_rows, np.array(python), rtol=1e-8, atol=1e-12)


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


@pytest.mark.parametrize("kind, alpha", [("ekf", None), ("ukf", 1.0), ("ukf", 1e-3)])
def test_single_precision_holds_where_the_numerics_allow(tmp_path, kind, alpha):
    """precision="single" (float): on the short-period record (seed 3) the EKF's and the UKF's (alpha
    = 1) states stay within 1e-5 of their range of the double filter's (measured 2.2e-7 and 5.1e-7)
    with P positive definite, the object compiled under -Wdouble-promotion -Werror and calling no
    double libm function; the UKF with alpha = 1e-3 (weights ~1e6) loses its innovation
    covariance and then its prediction: the step returns 1 (FL_EVALUATION_FAILED, sample 120 here)
    and keeps the last good state, as the generated header says."""
    if CC is None:
        pytest.skip("no C compiler on this machine")
    m = casest.load_model_file("short_period")
    model, data = m.model(), m.simulate(seed=3)
    R = [m.NOISE_STD[n] ** 2 for n in model.output_names]
    arguments = (model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-4)
    flt = casest.UnscentedKalmanFilter(*arguments, x0=np.zeros(2), alpha=alpha) if kind == "ukf" else \
        casest.ExtendedKalmanFilter(*arguments, x0=np.zeros(2))
    paths = export_c(flt, tmp_path / "out", name="fl", precision="single")
    assert "typedef float fl_real" in open(paths["header"]).read()
    obj = tmp_path / "fl.o"  # float throughout: no promotion to double, no double libm call
    subprocess.run([CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-Wdouble-promotion", "-Werror", "-c", paths["source"],
                    "-o", str(obj)], check=True)
    undefined = {u.split("@")[0] for u in subprocess.run(["nm", "-u", str(obj)], capture_output=True,
                                                          text=True).stdout.split() if u != "U"}
    assert not undefined & {"sqrt", "log", "exp", "fabs", "fmax", "pow"}, undefined
    driver = tmp_path / "driver.c"
    driver.write_text(FLOAT_DRIVER)
    exe = tmp_path / "driver"
    subprocess.run([CC, "-std=c99", "-O2", "-Wall", f"-I{tmp_path / 'out'}", str(driver), paths["source"], "-lm", "-o",
                    str(exe)], check=True)
    D, _ = record_columns(model, data)
    noise = getattr(flt, "input_noise", np.zeros(len(model.inputs)))
    numbers = [*flt.x0, *flt.P0.reshape(-1, order="F"), *flt.theta, *flt.Qc.reshape(-1, order="F"), *noise,
               *flt.R.reshape(-1, order="F")]
    text = f"{data.n_samples} " + " ".join(repr(float(v)) for v in numbers) + "\n" + \
        "\n".join(" ".join(repr(float(v)) for v in row) for row in D)
    lines = subprocess.run([str(exe)], input=text, capture_output=True, text=True, check=True).stdout.splitlines()
    if alpha == 1e-3:
        assert lines[-1].startswith("flag 1 ")  # FL_EVALUATION_FAILED: its prediction is not finite
        return
    out = np.array([[float(v) for v in line.split()] for line in lines])
    reference = flt.filter(data, compiled=True)
    span = np.abs(reference.x_filtered).max(axis=0)
    assert np.all(np.abs(out[:, :2] - reference.x_filtered).max(axis=0) <= 1e-5 * span)
    P = out[:, 2:6].reshape(-1, 2, 2, order="F")
    assert np.all(np.linalg.eigvalsh(0.5 * (P + P.transpose(0, 2, 1))) > 0)


def test_a_step_above_the_stated_size_is_refused_by_its_count(tmp_path, case):
    """The limit is stated in operations (max_instructions): the short-period EKF's step, a few
    thousand operations, is refused under a limit of 100 with its count named, and nothing is written."""
    m, model, data, R = case
    ekf = casest.ExtendedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-4)
    with pytest.raises(casest.OptionError, match=r"operations .* more than max_instructions = 100"):
        export_c(ekf, tmp_path / "out", name="fl", max_instructions=100)
    assert not (tmp_path / "out").exists()


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


@pytest.mark.parametrize("precision", ["double", "single"])
def test_the_static_analyser_finds_nothing(tmp_path, case, precision):
    """cppcheck (warning, portability and performance checks) on the UKF's export: no finding.
    Skipped, saying so, where cppcheck is not installed."""
    if shutil.which("cppcheck") is None:
        pytest.skip("cppcheck is not installed (apt install cppcheck)")
    m, model, data, R = case
    flt = casest.UnscentedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-4)
    paths = export_c(flt, tmp_path / "out", name="fl", precision=precision)
    run = subprocess.run(["cppcheck", "--std=c99", "--enable=warning,portability,performance", "--error-exitcode=1",
                          "-q", f"-I{tmp_path / 'out'}", paths["source"]], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
