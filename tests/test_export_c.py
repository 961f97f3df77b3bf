"""The EKF, IEKF and UKF generated as C (casest.export_c): compiled with the system compiler and run
over a record by a small C driver, every sample's x(k|k), P(k|k) and innovation equal casest's
compiled filter pass (the same step: 1e-12; the log-likelihood summed over the record too) and its
step-by-step NumPy filter (1e-9); the
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
from c_export_drivers import DRIVER, FLOAT_DRIVER, short_period_case

CC = shutil.which("cc") or shutil.which("gcc")

@pytest.fixture(scope="module")
def case():
    return short_period_case()


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
    # each line ends with the step's log-likelihood (its logarithms taken in the accessor)
    driver.write_text(DRIVER.replace('printf("\\n");', 'printf("%.17g\\n", NAME_log_likelihood(&f));')
                      .replace("NAME_UPPER", "FL").replace("NAME", "fl"))
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
    x_c, P_c, e_c = out[:, :n], out[:, n:n + n * n].reshape(-1, n, n, order="F"), out[:, n + n * n:-1]
    compiled = ekf.filter(data, compiled=True)
    assert np.sum(out[:, -1]) == pytest.approx(compiled.log_likelihood, rel=1e-12)
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
