"""The newest features' bad inputs for ``bad_input_cases.py``: merged limits, artificial stabilisation,
signal smoothing, lookup tables, log readers, filter-error options, settings, pages, outputs and the
compile cache (the cases of the last reliability review not listed there before).

Each entry: case name -> (class of the input, the call), as ``bad_input_cases.cases`` gives them.
"""

from __future__ import annotations

import os
import subprocess
import sys

import casadi as ca
import numpy as np

import casest

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.join(HERE, "..", "..")


class Handled(str):
    """What a case checked of an input handled correctly (``bad_input_cases.classify`` reads its type name)."""


def _two_exponentials() -> casest.Model:
    xs = ca.SX.sym("x")
    c, a0, a1, b0, b1 = (ca.SX.sym(n) for n in ("c", "a0", "a1", "b0", "b1"))
    params = [casest.Parameter("c", nominal=0.0), casest.Parameter("a0", nominal=0.0),
              casest.Parameter("b0", 0.01, 10.0, prior=casest.LogUniform()), casest.Parameter("a1", nominal=0.0),
              casest.Parameter("b1", 0.01, 10.0, prior=casest.LogUniform())]
    return casest.Model(params, ["x"], {"y": c + a0 * ca.exp(-b0 * xs) + a1 * ca.exp(-b1 * xs)})


def _limit_model(*arguments):
    from casest.two_stage.merged_limit import limit_model

    return limit_model(*arguments)


def _unstable():
    mf = casest.load_model_file(os.path.join(REPO, "models", "unstable.py"))
    return mf.model()


def _lowpass(y, cutoff):
    from casest.data.smoothing import zero_phase_lowpass

    return zero_phase_lowpass(y, 0.01, cutoff)


def _truncated_ulog(folder):
    """The bundled PX4 log cut at 60 % of its bytes, read with the fields of the log-reader tests."""
    source = casest.bundled_data_dir("px4_ulog", "sample_log_small.ulg")
    path = os.path.join(folder, "truncated.ulg")
    with open(source, "rb") as fh:
        raw = fh.read()
    with open(path, "wb") as fh:
        fh.write(raw[: int(0.6 * len(raw))])
    q, k = ca.SX.sym("q"), ca.SX.sym("k")
    model = casest.Model([casest.Parameter("k", -10.0, 10.0)], [casest.Signal("q")], {"p": k * q})
    return casest.Dataset.from_ulog(model, path, {"q": "vehicle_angular_velocity.xyz[1]",
                                                  "p": "sensor_combined.gyro_rad[0]"})


def _html_with(folder, model=None, data=None):
    scalar2 = casest.load_model_file("scalar2")
    est = casest.estimate(scalar2.model(), scalar2.simulate(0))
    return est.to_html(os.path.join(folder, "page.html"), model=model, data=data)


def _innovation(**options):
    tl = casest.load_model_file("turbulent_longitudinal")
    return casest.filter_error_estimate(tl.model(), tl.simulate(1, n_samples=300), tl.TURBULENCE_START,
                                        start=tl.TRUTH, formulation="innovation", **options)


def _cli(folder, *arguments, stdin=None):
    """``python3 -m casest ARGUMENTS`` in ``folder``: a casest error for exit 1 or 2, else what it printed."""
    run = subprocess.run([sys.executable, "-m", "casest", *arguments], capture_output=True, text=True,
                         timeout=600, cwd=folder, stdin=stdin)
    if run.returncode in (1, 2):
        raise casest.OptionError(run.stderr.strip().splitlines()[-1] if run.stderr.strip() else f"exit {run.returncode}")
    if run.returncode:
        raise RuntimeError(f"exit {run.returncode}: {run.stderr[-300:]}")
    return run


def _json_to_dash(folder):
    """``--json -`` writes the estimate to standard output."""
    run = _cli(folder, "solve", "scalar2", "--quick", "--quiet", "--json", "-")
    if not run.stdout.lstrip().startswith("{"):
        raise AssertionError(f"standard output starts {run.stdout[:40]!r}")
    return Handled("the JSON on standard output")


def _report_redirected(folder):
    """``casest solve scalar2 --quick > out.txt``: the printed report is in the file."""
    path = os.path.join(folder, "out.txt")
    with open(path, "w") as out:
        run = subprocess.run([sys.executable, "-m", "casest", "solve", "scalar2", "--quick"], stdout=out,
                             stderr=subprocess.DEVNULL, timeout=600, cwd=folder)
    with open(path) as fh:
        text = fh.read()
    if run.returncode or "[[Conclusion]]" not in text:
        raise AssertionError(f"exit {run.returncode}; the file holds {text[:60]!r}")
    return Handled("the report in the redirected file")


def _cache_dir_is(folder, kind):
    """``casest cache info`` with CASEST_CACHE_DIR a regular file or a dangling link."""
    path = os.path.join(folder, f"cache_{kind}")
    if kind == "file":
        with open(path, "w") as fh:
            fh.write("not a folder\n")
    else:
        os.symlink(os.path.join(folder, "nowhere"), path)
    env = {**os.environ, "CASEST_CACHE_DIR": path}
    run = subprocess.run([sys.executable, "-m", "casest", "cache", "info"], capture_output=True, text=True,
                         timeout=120, cwd=folder, env=env)
    if run.returncode == 0:
        return run.stdout.strip()  # silent: classified by the words it printed
    raise casest.OptionError((run.stderr or run.stdout).strip().splitlines()[-1])


def _html_to_stdout(folder):
    """``casest solve scalar2 --quick --quiet --html /dev/stdout > page.html``: the page is in the file."""
    path = os.path.join(folder, "page_out.html")
    with open(path, "w") as out:
        run = subprocess.run([sys.executable, "-m", "casest", "solve", "scalar2", "--quick", "--quiet", "--html",
                              "/dev/stdout"], stdout=out, stderr=subprocess.DEVNULL, timeout=600, cwd=folder)
    with open(path) as fh:
        text = fh.read()
    if run.returncode or not text.startswith("<!DOCTYPE html>"):
        raise AssertionError(f"exit {run.returncode}; the file starts {text[:40]!r}")
    return Handled("the page written into the redirected file")


def _slow_model_file(folder):
    """A model file that sleeps 12 s at import: ``casest solve`` says what it waits for, then solves."""
    path = os.path.join(folder, "sleepy.py")
    with open(path, "w") as fh:
        fh.write("import time\ntime.sleep(12)\nfrom casest._models.scalar2 import model, simulate  # noqa\n")
    run = subprocess.run([sys.executable, "-m", "casest", "solve", path, "--quick", "--quiet"], capture_output=True,
                         text=True, timeout=600, cwd=folder)
    if run.returncode or "still importing model file" not in run.stderr:
        raise AssertionError(f"exit {run.returncode}; standard error: {run.stderr[-200:]!r}")
    return Handled("said after 10 s that it waits for the file's own code, then solved")


def _ekf_compiled_yes():
    sp = casest.load_model_file("short_period")
    model = sp.model()
    ekf = casest.ExtendedKalmanFilter(model, sp.TRUTH, {"q": 1e-4}, [sp.NOISE_STD[n] ** 2 for n in model.output_names],
                                      np.eye(2) * 1e-6, x0=np.zeros(2))
    return ekf.filter(sp.simulate(0), compiled="yes")


def _mat_units_of_a_column_not_read(folder):
    import scipy.io

    scalar2 = casest.load_model_file("scalar2")
    model, data = scalar2.model(), scalar2.simulate(0)
    columns = {name: data.column(name) for name in (*data.signal_names, *data.output_names)}
    path = os.path.join(folder, "record.mat")
    scipy.io.savemat(path, columns)
    return casest.Dataset.from_mat(model, path, units={"nope": "deg"})


def _plausible_edit():
    """A saved estimate with one value moved by 1 % (inside its bounds: every field check passes)."""
    import json

    m = casest.load_model_file("scalar1")
    data = json.loads(casest.estimate(m.model(), m.simulate(seed=0)).to_json())
    data["theta"]["array"]["values"][0] *= 1.01
    return casest.Estimate.from_json(json.dumps(data))


def _fresh_symbols(alpha, columns):
    """A term built from a symbol made afresh with the data column's name is that column: the fit
    recovers cm = 0.1 + 0.5 alpha + 0.2 alpha^2 (noise 0.01) within 4 std."""
    fit = casest.regress("cm", {"bias": 1, "alpha": alpha, "alpha2": ca.SX.sym("alpha") ** 2}, columns)
    if np.any(np.abs(fit.theta - [0.1, 0.5, 0.2]) > 4 * fit.std):
        raise AssertionError(f"estimates {fit.theta} with std {fit.std}")
    return Handled("the fresh symbol matched by name; estimates within 4 std of the truth")


def feature_cases(folder: str) -> dict:
    """Case name -> (class of the input, the call)."""
    x = np.linspace(0.0, 1.0, 200)
    alpha = ca.SX.sym("alpha")
    noise = 0.01 * np.random.default_rng(5).standard_normal(x.size)
    columns = {"alpha": x, "cm": 0.1 + 0.5 * x + 0.2 * x**2 + noise}
    return {
        "regress with terms of fresh symbols": ("equation error", lambda: _fresh_symbols(alpha, columns)),
        "limit_model index out of range": ("merged limit", lambda: _limit_model(_two_exponentials(), [(9, 1)], (0, 1))),
        "limit_model of no pairs": ("merged limit", lambda: _limit_model(_two_exponentials(), [], (1, 3))),
        "limit_model of terms not exchangeable": ("merged limit", lambda: _limit_model(_two_exponentials(), [(2, 0)],
                                                                                        (1, 3))),
        "limit_model of a DynamicModel": ("merged limit", lambda: _limit_model(
            casest.load_model_file("short_period").model(), [(0, 1)], (2, 3))),
        "MergedLimit.from_dict({})": ("merged limit", lambda: __import__(
            "casest.two_stage.merged_limit", fromlist=["x"]).MergedLimit.from_dict({})),
        "artificially_stabilised of a static Model": ("stabilisation", lambda: casest.artificially_stabilised(
            casest.load_model_file("scalar2").model(), np.eye(1))),
        "artificially_stabilised(-5 I)": ("stabilisation", lambda: casest.artificially_stabilised(_unstable(),
                                                                                                  -5 * np.eye(2))),
        "stabilised_dataset of a dict": ("stabilisation", lambda: casest.stabilised_dataset(
            casest.artificially_stabilised(_unstable(), np.diag([1.3, 1.3])), {"t": [0.0]})),
        "zero_phase_lowpass cutoff 1e-9": ("smoothing", lambda: _lowpass(np.sin(np.arange(500.0)), 1e-9)),
        "zero_phase_lowpass of a complex signal": ("smoothing", lambda: _lowpass(np.exp(1j * np.arange(500.0)), 5.0)),
        "lookup table with a NaN value": ("models", lambda: casest.lookup_table("cl", [[0.0, 1.0, 2.0]],
                                                                                [0.0, np.nan, 1.0])),
        "from_ulog of a truncated log": ("input path", lambda: _truncated_ulog(folder)),
        "to_html(model=, data={'a': 5})": ("pages", lambda: _html_with(folder, casest.load_model_file("scalar2").model(),
                                                                      {"a": 5})),
        "to_html(model=another model)": ("pages", lambda: _html_with(folder, casest.load_model_file("scalar1").model())),
        "filter error innovation max_iter=0": ("filter error", lambda: _innovation(max_iter=0)),
        "filter error innovation with P0": ("filter error", lambda: _innovation(P0=np.eye(4))),
        "SweepSettings(scheduler=12345)": ("settings", lambda: casest.SweepSettings(scheduler=12345)),
        "IEKF max_iterations=0": ("filters", lambda: casest.ExtendedKalmanFilter(
            casest.load_model_file("short_period").model(), casest.load_model_file("short_period").model().nominal,
            np.zeros(2), np.ones(3), np.eye(2), iterated=True, max_iterations=0)),
        "--figure fig.xyz": ("command line", lambda: _cli(folder, "solve", "scalar2", "--quick", "--quiet",
                                                         "--figure", "fig.xyz")),
        "--json - (standard output)": ("output path", lambda: _json_to_dash(folder)),
        "solve > out.txt keeps the report": ("output path", lambda: _report_redirected(folder)),
        "CASEST_CACHE_DIR a regular file": ("cache", lambda: _cache_dir_is(folder, "file")),
        "CASEST_CACHE_DIR a dangling link": ("cache", lambda: _cache_dir_is(folder, "link")),
        "--html /dev/stdout > page.html": ("output path", lambda: _html_to_stdout(folder)),
        "a model file that sleeps 12 s at import": ("models", lambda: _slow_model_file(folder)),
        "EKF.filter(compiled='yes')": ("filters", _ekf_compiled_yes),
        "from_mat(units=) of a column not read": ("input path", lambda: _mat_units_of_a_column_not_read(folder)),
        "result file with a value moved by 1 %": ("result files", _plausible_edit),
    }
