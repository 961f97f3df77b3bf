"""Every bad input gets a clear message (or is handled correctly), never a silent wrong answer.

Data come from the bundled scalar examples (paper Sec. III) with fixed seeds; where an
estimate is checked, the expected value is the estimate on the clean data.
"""

import fcntl
import json
import math
import sys

import casadi as ca
import numpy as np
import pytest

import casest
from casest.apps.cli import main as cli

scalar1 = casest.load_model_file("scalar1")


@pytest.fixture(scope="module")
def clean():
    model, data = scalar1.model(), scalar1.simulate(0)
    return model, data, casest.estimate(model, data)


def _write(path, text, encoding="utf-8"):
    path.write_text(text, encoding=encoding)
    return path


def _csv(data, delimiter=",", header=("eta [rad]", "z"), eta_scale=1.0):
    rows = [delimiter.join(header)]
    rows += [delimiter.join([repr(float(e * eta_scale)), repr(float(z))]) for e, z in zip(data.column("eta"), data.column("z"))]
    return "\n".join(rows) + "\n"


# ----------------------------------------------------------------------------- CSV files
def test_unit_in_degrees_is_converted(tmp_path, clean):
    """eta declared in rad, the file in degrees: converted (pint), so the estimate is the clean one
    (a = -0.925 for a truth of 1 when degrees were read as radians)."""
    model, data, ref = clean
    path = _write(tmp_path / "deg.csv", _csv(data, header=("eta [deg]", "z"), eta_scale=180 / math.pi))
    with pytest.warns(UserWarning, match=r"converted from \[deg\] to \[rad\]"):
        back = casest.Dataset.from_csv(model, path)
    np.testing.assert_allclose(back.column("eta"), data.column("eta"), rtol=1e-12)
    np.testing.assert_allclose(casest.estimate(model, back).theta, ref.theta, rtol=1e-8)


def test_unit_that_cannot_be_converted_is_refused(tmp_path, clean):
    model, data, _ = clean
    path = _write(tmp_path / "m.csv", _csv(data, header=("eta [m]", "z")))
    with pytest.raises(casest.DataError, match=r"\[m\] but the model declares \[rad\].*cannot be converted"):
        casest.Dataset.from_csv(model, path)


def test_unit_without_pint_is_refused(tmp_path, clean, monkeypatch):
    model, data, _ = clean
    path = _write(tmp_path / "deg.csv", _csv(data, header=("eta [deg]", "z")))
    monkeypatch.setitem(sys.modules, "pint", None)  # as if pint were not installed
    with pytest.raises(casest.DataError, match=r"install pint .*casest\[units\]"):
        casest.Dataset.from_csv(model, path)


def test_duplicated_column_names(tmp_path, clean):
    model, data, _ = clean
    text = "eta,z,z\n" + "".join(f"{e},{z},{z}\n" for e, z in zip(data.column("eta"), data.column("z")))
    with pytest.raises(casest.DataError, match=r"duplicated column name.*'z' in columns \[2, 3\]"):
        casest.Dataset.from_csv(model, _write(tmp_path / "dup.csv", text))


def test_byte_order_mark_is_ignored(tmp_path, clean):
    model, data, _ = clean
    path = _write(tmp_path / "bom.csv", _csv(data), encoding="utf-8-sig")
    assert path.read_bytes()[:3] == b"\xef\xbb\xbf"
    np.testing.assert_array_equal(casest.Dataset.from_csv(model, path).column("eta"), data.column("eta"))


@pytest.mark.parametrize("delimiter", [";", "\t"])
def test_semicolon_and_tab_are_detected(tmp_path, clean, delimiter):
    model, data, _ = clean
    path = _write(tmp_path / "d.csv", _csv(data, delimiter=delimiter))
    np.testing.assert_array_equal(casest.Dataset.from_csv(model, path).column("z"), data.column("z"))


def test_decimal_comma_is_named(tmp_path, clean):
    model, _, _ = clean
    path = _write(tmp_path / "eu.csv", "eta;z\n1,5;2,0\n")
    with pytest.raises(casest.DataError, match="decimal comma"):
        casest.Dataset.from_csv(model, path)


def test_unknown_delimiter_is_named(tmp_path, clean):
    model, _, _ = clean
    path = _write(tmp_path / "pipe.csv", "eta|z\n1|2\n")
    with pytest.raises(casest.DataError, match="not separated by a comma, semicolon or tab"):
        casest.Dataset.from_csv(model, path)


@pytest.mark.parametrize("cell", ["eta [rad", "eta rad]", "eta [rad] [deg]", "[rad]"])
def test_brackets_that_do_not_parse(tmp_path, clean, cell):
    model, data, _ = clean
    path = _write(tmp_path / "b.csv", _csv(data, header=(cell, "z")))
    with pytest.raises(casest.DataError, match="does not parse"):
        casest.Dataset.from_csv(model, path)


def test_folder_and_binary_file_as_data(tmp_path, clean):
    model, _, _ = clean
    with pytest.raises(casest.DataError, match="is a folder"):
        casest.Dataset.from_csv(model, tmp_path)
    binary = tmp_path / "data.npy"
    np.save(binary, np.arange(10.0))
    with pytest.raises(casest.DataError, match="binary file"):
        casest.Dataset.from_csv(model, binary)


# ----------------------------------------------------------------------------- magnitudes
def _scaled_problem(scale):
    a, b, c, eta = (ca.SX.sym(n) for n in ("a", "b", "c", "eta"))
    model = casest.Model([casest.Parameter("a", prior=casest.Gaussian(0, scale)), casest.Parameter("b", 0, 0.2),
                          casest.Parameter("c", prior=casest.Gaussian(0, scale))],
                         ["eta"], {"z": (scale + a) * ca.cos(eta + b) + c}, name="scaled")
    d = scalar1.simulate(0)
    return model, {"eta": d.column("eta"), "z": d.column("z") * scale}


def test_huge_values_are_explained():
    """Outputs ~1e300 used to end in 'rank-deficient at every candidate'."""
    model, cols = _scaled_problem(1e300)
    with pytest.raises(casest.DataError, match=r"'z' reaches .*overflow double precision.*larger unit"):
        casest.Dataset(model, cols)


def test_tiny_outputs_are_estimated(clean):
    """Outputs ~1e-12: the same estimate, scaled (it used to end after 1000 IPOPT iterations)."""
    _, _, ref = clean
    model, cols = _scaled_problem(1e-12)
    est = casest.estimate(model, casest.Dataset(model, cols))
    assert est.success and est.n_iterations < 200
    np.testing.assert_allclose(est.theta[[0, 2]], ref.theta[[0, 2]] * 1e-12, rtol=1e-6)
    np.testing.assert_allclose(est.theta[1], ref.theta[1], rtol=1e-6)


def test_underflowing_values_are_explained():
    model, cols = _scaled_problem(1.0)
    cols["z"] = cols["z"] * 1e-160
    with pytest.raises(casest.DataError, match="underflow"):
        casest.Dataset(model, cols)


# ----------------------------------------------------------------------------- models
def test_model_output_nan_at_some_samples():
    """log(eta - 5) on eta in [1, 10]: the output and samples are named (was 'SVD did not converge')."""
    a, b, eta = ca.SX.sym("a"), ca.SX.sym("b"), ca.SX.sym("eta")
    model = casest.Model([casest.Parameter("a"), casest.Parameter("b", 0, 1)], ["eta"],
                         {"z": a * ca.log(eta - 5) + b * eta}, name="nanmodel")
    e = np.linspace(1, 10, 50)
    data = casest.Dataset(model, {"eta": e, "z": e + 0.1})
    with pytest.raises(casest.ModelError, match=r"output 'z' is NaN or infinite at 22 of 50 samples .*eta = 1"):
        casest.estimate(model, data)


@pytest.mark.parametrize("kwargs, message", [
    ({"lb": float("nan"), "ub": 5.0}, "lower bound is NaN; use -inf for no bound"),
    ({"lb": 0.0, "ub": float("nan")}, "upper bound is NaN; use inf for no bound"),
    ({"lb": "0", "ub": 5.0}, r"lower bound '0' is a str, not a number; write lb=float\('0'\)"),
    ({"nominal": "1"}, "nominal value .1. is a str, not a number"),
])
def test_bad_bounds(kwargs, message):
    with pytest.raises(casest.ModelError, match=message):
        casest.Parameter("a", **kwargs)


def test_vector_mx_symbol_is_accepted():
    m, k = ca.MX.sym("m", 3), ca.MX.sym("k")
    model = casest.Model([casest.Parameter("k")], ["m_0", "m_1", "m_2"], {"z": k * (m[0] + m[1] * m[2])})
    assert float(model.predict([2.0], np.array([[1.0, 2.0, 3.0]]))[0, 0]) == 14.0
    with pytest.raises(casest.ModelError, match=r"vector symbol 'm' .* must be declared.*missing: \['m_1', 'm_2'\]"):
        casest.Model([casest.Parameter("k")], ["m_0"], {"z": k * m[0] + m[1]})


def test_casadi_function_as_output():
    a, eta = ca.SX.sym("a"), ca.SX.sym("eta")
    f = ca.Function("h", [a, eta], [a * ca.sin(eta)], ["a", "eta"], ["z"])
    model = casest.Model([casest.Parameter("a")], ["eta"], {"z": f})
    np.testing.assert_allclose(model.predict([2.0], np.array([[0.5]]))[0, 0], 2 * np.sin(0.5), rtol=1e-15)
    unnamed = ca.Function("g", [a, eta], [a * eta])
    with pytest.raises(casest.ModelError, match=r"inputs \['i0', 'i1'\].*name its inputs after them"):
        casest.Model([casest.Parameter("a")], ["eta"], {"z": unnamed})


# ----------------------------------------------------------------------------- command line
def _run(capsys, *argv):
    status = cli(list(argv))
    out = capsys.readouterr()
    return status, out.out, out.err


def test_user_error_is_two_lines_and_status_2(capsys, tmp_path):
    status, out, err = _run(capsys, "solve", "scalar1", "--data", str(tmp_path / "missing.csv"))
    assert status == 2
    assert "Traceback" not in err and len(err.strip().splitlines()) <= 2
    assert "does not exist" in err


def test_debug_shows_the_traceback(tmp_path):
    with pytest.raises(casest.DataError):
        cli(["solve", "scalar1", "--data", str(tmp_path / "missing.csv"), "--debug"])


def test_unknown_model_names_the_bundled_ones(capsys):
    status, _, err = _run(capsys, "solve", "no_such_model")
    assert status == 2 and "bundled models" in err and "scalar2" in err


def test_internal_error_asks_for_a_report(capsys, monkeypatch):
    monkeypatch.setattr("casest.apps.cli.cmd_models", lambda args: 1 / 0)
    monkeypatch.setattr("casest.apps.cli.build_parser", _parser_with_models_bug)
    status, _, err = _run(capsys, "models")
    assert status == 3 and "Traceback" in err and "please report it" in err


def _parser_with_models_bug():
    import argparse

    parser = argparse.ArgumentParser(prog="casest")
    sub = parser.add_subparsers(dest="command")
    sub.add_parser("models").set_defaults(func=lambda args: 1 / 0)
    return parser


@pytest.mark.parametrize("argv, message", [
    (["solve", "scalar1", "--seed", "-1"], "is negative"),
    (["mc", "scalar1", "--runs", "0", "--out", "x"], "must be at least 1"),
    (["mc", "scalar1", "--runs", "-3", "--out", "x"], "must be at least 1"),
    (["solve", "scalar1", "--seed", "one"], "not an integer"),
])
def test_bad_numbers_on_the_command_line(capsys, argv, message):
    with pytest.raises(SystemExit) as exit_info:
        cli(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_json_onto_a_folder_fails_before_solving(capsys, tmp_path):
    status, out, err = _run(capsys, "solve", "scalar1", "--json", str(tmp_path))
    assert status == 2 and "is a folder; give a file name" in err
    assert "[[Parameters]]" not in out  # refused before any work, nothing lost


def test_truncated_and_foreign_json_results(tmp_path, clean):
    _, _, est = clean
    good = tmp_path / "e.json"
    est.to_json(good)
    truncated = tmp_path / "t.json"
    truncated.write_text(good.read_text()[:200])
    with pytest.raises(casest.ResultFileError, match=r"t.json' is truncated"):
        casest.Estimate.from_json(truncated)
    foreign = tmp_path / "f.json"
    foreign.write_text(json.dumps({"format": "something else", "theta": [1, 2]}))
    with pytest.raises(casest.ResultFileError, match=r"f.json'.*not a casest estimate"):
        casest.Estimate.from_json(foreign)
    with pytest.raises(casest.ResultFileError, match="does not exist"):
        casest.Estimate.from_json(tmp_path / "nothing.json")


def test_corrupt_campaign_config(tmp_path):
    from casest.apps.montecarlo import CampaignConfig, CampaignError, run_campaign

    (tmp_path / "config.json").write_text('{"model": "x", "first_se')
    config = CampaignConfig(model=scalar1.__file__)
    with pytest.raises(CampaignError, match="not a valid campaign configuration"):
        run_campaign(config, 2, str(tmp_path), progress=False)


def test_two_campaigns_on_one_folder(tmp_path):
    """A second campaign on a folder whose lock is held stops at once (runs were computed twice)."""
    from casest.apps.montecarlo import CampaignConfig, CampaignError, run_campaign

    with open(tmp_path / ".lock", "a+") as held:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        held.write("12345")
        held.flush()
        with pytest.raises(CampaignError, match=r"another campaign is running on .*12345"):
            run_campaign(CampaignConfig(model=scalar1.__file__), 2, str(tmp_path), progress=False)
        # the running campaign has begun an atomic write (a .tmp_ copy): still "another campaign is running"
        (tmp_path / ".tmp_abc123").write_text("{")
        with pytest.raises(CampaignError, match=r"another campaign is running on .*12345"):
            run_campaign(CampaignConfig(model=scalar1.__file__), 2, str(tmp_path), progress=False)
    assert not (tmp_path / "runs.jsonl").exists()


def test_a_killed_campaigns_temporary_copies_are_cleaned_on_the_next_start(tmp_path):
    """kill -9 during an atomic write leaves a .tmp_ copy: the next campaign on the folder removes it."""
    from casest.apps.montecarlo import CampaignConfig, run_campaign

    (tmp_path / ".tmp_left_by_kill").write_text("{")
    run_campaign(CampaignConfig(model=scalar1.__file__), 2, str(tmp_path), workers=1, progress=False)
    assert not list(tmp_path.glob(".tmp_*")) and (tmp_path / "config.json").exists()


def test_output_unit_is_converted_too(tmp_path):
    """An output declared in m/s, the file in km/h: converted, not read as m/s."""
    k, t = ca.SX.sym("k"), ca.SX.sym("t")
    model = casest.Model([casest.Parameter("k")], [casest.Signal("t", "s")], {"v": k * t}, name="ramp",
                         output_units={"v": "m/s"})
    path = _write(tmp_path / "v.csv", "t [s],v [km/h]\n1,3.6\n2,7.2\n3,10.8\n")
    with pytest.warns(UserWarning, match=r"'v' converted from \[km/h\] to \[m/s\]"):
        data = casest.Dataset.from_csv(model, path)
    np.testing.assert_allclose(data.column("v"), [1.0, 2.0, 3.0], rtol=1e-12)
    with pytest.raises(casest.ModelError, match=r"output_units names \['w'\]"):
        casest.Model([casest.Parameter("k")], ["t"], {"v": k * t}, output_units={"w": "m"})


@pytest.mark.parametrize("kwargs, nominal", [
    ({"lb": 1.0, "ub": 3.0}, 2.0),                                  # box midpoint (0.0 lay outside the box)
    ({"lb": 1e-3, "ub": 1e3, "prior": casest.LogUniform()}, 1.0),   # geometric mean
    ({"prior": casest.Gaussian(5.0, 1.0)}, 5.0),                    # prior mean
    ({"lb": 2.0}, 2.0),                                             # 0 moved into a half-open box
    ({}, 0.0),
])
def test_default_nominal(kwargs, nominal):
    """A parameter declared without a nominal value no longer fails with 'nominal value 0.0 lies outside'."""
    assert casest.Parameter("k", **kwargs).nominal == pytest.approx(nominal)


def test_model_file_protocol(tmp_path, capsys):
    """The hooks a model file may offer are one dataclass; a campaign names what is missing."""
    hooks = casest.model_file_hooks(casest.load_model_file("pitot5hole"))
    assert hooks.stage_data is not None and hooks.sweep_settings is not None and hooks.truth is not None
    bare = tmp_path / "bare.py"
    bare.write_text("import casadi as ca, casest\n"
                    "def model():\n"
                    "    a, x = ca.SX.sym('a'), ca.SX.sym('x')\n"
                    "    return casest.Model([casest.Parameter('a')], ['x'], {'y': a * x})\n")
    assert cli(["mc", str(bare), "--runs", "2", "--out", str(tmp_path / "o")]) == 2
    assert "lacks ['simulate', 'TRUTH'], which a campaign needs" in capsys.readouterr().err
    exported = tmp_path / "exported.py"
    exported.write_text(bare.read_text() + "TRUTH = {'a': 2.0}\nHOOKS = casest.ModelFileHooks(model=model, truth=TRUTH)\n")
    assert casest.model_file_hooks(casest.load_model_file(str(exported))).truth == {"a": 2.0}
    wrong = tmp_path / "wrong.py"
    wrong.write_text(bare.read_text() + "TRUTH = [2.0]\n")
    with pytest.raises(casest.ModelFileError, match="TRUTH in the model file must be a mapping"):
        casest.model_file_hooks(casest.load_model_file(str(wrong)))


# ----------------------------------------------------------------------------- one exception root
def test_every_casest_exception_is_a_casest_error():
    """``except casest.CasestError`` catches every mistake casest reports, and keeps the built-in bases."""
    import casest.errors
    from casest.apps.cli import UsageError

    classes = [getattr(casest.errors, n) for n in casest.errors.__all__ if n != "CasestError"] + [UsageError]
    for cls in classes:
        builtin = ImportError if cls is casest.errors.MissingExtraError else ValueError
        assert issubclass(cls, casest.CasestError) and issubclass(cls, builtin), cls
    assert issubclass(casest.ModelFileError, FileNotFoundError)
    assert casest.ModelError is casest.models.ModelError and casest.DataError is casest.data.DataError


_BARE_MODEL = ("import casadi as ca, casest\n"
               "def model():\n"
               "    a, x = ca.SX.sym('a'), ca.SX.sym('x')\n"
               "    return casest.Model([casest.Parameter('a', -5, 5)], ['x'], {'y': a * x})\n")


def test_model_file_that_raises_at_import_is_a_user_error(tmp_path, capsys):
    broken = tmp_path / "broken.py"
    broken.write_text("import casest\nTABLE = {}\nGAIN = TABLE['gain']\n" + _BARE_MODEL)
    status, _, err = _run(capsys, "solve", str(broken))
    assert status == 2 and "Traceback" not in err
    assert str(broken) in err and "KeyError at line 3" in err
    with pytest.raises(casest.ModelFileError, match="raised KeyError at line 3 while it was imported"):
        casest.load_model_file(str(broken))


def test_exception_inside_the_model_files_functions_is_a_user_error(tmp_path, capsys):
    """``simulate()`` of the user's file raises: exit 2 naming the file, the line and the function."""
    bad = tmp_path / "badsim.py"
    bad.write_text(_BARE_MODEL + "def simulate(seed):\n    raise RuntimeError('sensor table missing')\n")
    status, _, err = _run(capsys, "solve", str(bad))
    assert status == 2 and "Traceback" not in err
    assert f"{str(bad)!r} raised RuntimeError at line 6 (in simulate): sensor table missing" in err
    with pytest.raises(RuntimeError):
        cli(["solve", str(bad), "--debug"])


@pytest.mark.parametrize("text, message", [
    ("hello\n", "not a NIST StRD nonlinear-regression file"),
    ("Procedure: Nonlinear Least Squares Regression\nStarting Values (lines 41 to 42)\nData (lines 61 to 71)\n",
     "(cut off?)"),
])
def test_file_that_is_not_nist_is_a_user_error(tmp_path, capsys, text, message):
    path = _write(tmp_path / "odd.dat", text)
    status, _, err = _run(capsys, "nist", str(path))
    assert status == 2 and "Traceback" not in err and message in err


# ----------------------------------------------------------------------------- files are safe
def test_no_output_replaces_an_input(tmp_path, capsys):
    data = tmp_path / "victim.csv"
    assert cli(["solve", "scalar1", "--save-data", str(data)]) == 0
    original = data.read_text()
    capsys.readouterr()
    status, _, err = _run(capsys, "solve", "scalar1", "--data", str(data), "--json", str(data))
    assert status == 2 and "is the file given with --data" in err and data.read_text() == original
    status, _, err = _run(capsys, "solve", "scalar1", "--save-data", str(tmp_path / "x.csv"),
                          "--json", str(tmp_path / "x.csv"))
    assert status == 2 and "is the file given with --save-data" in err


def test_an_unwritable_output_folder_is_found_before_the_work(tmp_path, capsys, monkeypatch):
    """The probe fails (permissions, a read-only or full file system): exit 2 before solving,
    naming the user's path and the cause; no hidden temporary file is named."""
    import casest.apps.cli as cli_module
    import casest.apps.output_paths as output_paths

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(output_paths.tempfile, "NamedTemporaryFile", refuse)
    called = []
    monkeypatch.setattr(cli_module, "load_model_file", lambda *a: called.append(a))
    status, _, err = _run(capsys, "solve", "scalar1", "--json", str(tmp_path / "out.json"))
    assert status == 2 and not called
    assert f"--json {str(tmp_path / 'out.json')!r} cannot be written: Permission denied" in err and ".tmp" not in err


def test_a_failed_atomic_write_names_the_users_file(tmp_path, monkeypatch):
    import casest.data.files as files  # where atomic_write_text lives

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(files.tempfile, "mkstemp", refuse)
    with pytest.raises(OSError, match=r"cannot write '.*result.json' \(Permission denied\)"):
        files.atomic_write_text(tmp_path / "result.json", "{}")


# ----------------------------------------------------------------------------- entry points validate
def test_a_dynamic_model_without_inputs_is_estimated():
    """dx/dt = -k x, y = x (no input): stage 1 through the ODE used to fail on an empty input slice.
    Truth: k = 2 of the simulated record, within 3 std."""
    x, k = ca.SX.sym("x"), ca.SX.sym("k")
    model = casest.DynamicModel([casest.Parameter("k", 0.1, 5.0, 1.0)], [casest.State("x", 1.0)], [], {"x": -k * x},
                                {"y": x})
    t = np.arange(100) * 0.05
    _, clean = model.simulate({"k": 2.0}, model.dataset({"t": t, "y": np.zeros_like(t)}))
    noisy = clean[:, 0] + np.random.default_rng(0).normal(0, 0.01, t.size)
    est = casest.estimate(model, model.dataset({"t": t, "y": noisy}))
    assert est.success and abs(est.values["k"] - 2.0) < 3 * est.stds["k"]


def test_arguments_of_the_state_and_design_tools_are_checked(clean):
    from casest.filters import KalmanFilter

    from casest.recursive import ParameterEKF
    model, data, est = clean
    scalar2 = casest.load_model_file("scalar2")
    with pytest.raises(casest.OptionError, match="seed the filter with an estimate of this model"):
        ParameterEKF.from_estimate(scalar2.model(), est)
    kf = KalmanFilter(np.eye(1), np.eye(1), np.zeros((1, 1)), np.zeros((1, 1)), np.zeros(1), np.zeros((1, 1)))
    with pytest.raises(casest.OptionError, match="give a positive definite R"):
        kf.filter(np.ones((5, 1)))
    m2, d2 = scalar2.model(), scalar2.simulate(0)
    candidates = {f"b{k}": d2.subset(np.arange(20 * k, 20 * k + 20)) for k in range(5)}
    for kwargs, message in [({"budget": float("nan")}, "budget must be a positive finite number"),
                            ({"budget": 100.0, "max_repeats": -1}, "max_repeats must be a positive number")]:
        with pytest.raises(casest.OptionError, match=message):
            casest.design_experiment(m2, candidates, scalar2.TRUTH, [0.09], **kwargs)
    with pytest.raises(casest.OptionError, match="R must hold 1 positive finite noise variances"):
        casest.design_experiment(m2, candidates, scalar2.TRUTH, [0.0], budget=100.0)


def test_a_sweep_that_would_not_fit_in_memory_is_refused_with_the_figure(capsys):
    status, _, err = _run(capsys, "solve", "scalar2", "--candidates", "1000000000")
    assert status == 2 and "needs about" in err and "GiB" in err and "use fewer candidates" in err


def test_model_function_returning_nothing_is_a_user_error(tmp_path, capsys):
    path = tmp_path / "empty.py"
    path.write_text("import casest\ndef model():\n    pass\n")
    status, _, err = _run(capsys, "solve", str(path))
    assert status == 2 and "returned NoneType, not a casest.Model" in err


def test_a_figure_without_matplotlib_is_a_user_error(tmp_path, capsys, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_matplotlib(name, *args, **kwargs):
        if name.startswith("matplotlib"):
            raise ImportError("No module named 'matplotlib'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    status, _, err = _run(capsys, "sweep", "scalar1", "--figure", str(tmp_path / "l.png"), "--quiet")
    assert status == 2 and "pip install 'casest[plot]'" in err and "Traceback" not in err


def test_an_unusable_compile_cache_is_named_and_the_result_is_right(tmp_path, monkeypatch, capfd):
    from casest._casadi import numerics

    blocker = tmp_path / "a_file"
    blocker.write_text("")
    monkeypatch.setenv("CASEST_CACHE_DIR", str(blocker / "cache"))  # under a file: cannot be created
    x = ca.SX.sym("x")
    f = ca.Function("cache_probe_square", [x], [x * x + 0.125])
    with pytest.warns(RuntimeWarning, match="compile cache folder .* cannot be used"):
        g = numerics.compile_function(f)
    assert float(g(3.0)) == 9.125
    assert "Traceback" not in capfd.readouterr().err


def test_a_box_of_plus_minus_1e300_is_like_no_box(clean):
    """Found by the fuzz test: bounds +-1e300 made the parameter's scale 6e299 and the Hessian infinite."""
    import casadi as ca

    _, data, reference = clean
    a, b, c, eta = (ca.SX.sym(n) for n in ("a", "b", "c", "eta"))
    wide = casest.Model([casest.Parameter("a", lb=-1e300, ub=1e300), casest.Parameter("b", 0.0, 0.2, 0.0),
                         casest.Parameter("c", nominal=0.0, prior=casest.Gaussian(0.0, 1.0))], ["eta"],
                        {"z": (1 + a) * ca.cos(eta + b) + c})
    assert wide.parameters[0].typical_scale == 1.0
    est = casest.estimate(wide, casest.Dataset(wide, {"eta": data.column("eta"), "z": data.column("z")}))
    np.testing.assert_allclose(est.theta, reference.theta, rtol=1e-6)
    assert np.all(np.isfinite(est.std))


@pytest.mark.parametrize("call, message", [
    (lambda m, d: casest.estimate(m), "give the data"),
    (lambda m, d: casest.estimate(m, d, max_starts="3"), "max_starts must be an integer >= 1"),
    (lambda m, d: casest.SolverSettings(tol=-1.0), "SolverSettings.tol must be a positive finite number"),
    (lambda m, d: casest.SolverSettings(start_max_iter=0), "start_max_iter must be an integer >= 1"),
    (lambda m, d: casest.sweep(m, d, candidates=np.zeros((3, 5))), r"explicit candidates must be a finite \(M, 1\)"),
    (lambda m, d: casest.parameter_uncertainty(m, d, m.vector(scalar1.TRUTH), [1.0, 2.0]),
     "R must hold 1 positive finite noise variances"),
    (lambda m, d: __import__("casest.interop", fromlist=["ml_problem"]).ml_problem(m, -5), "N must be a positive"),
    (lambda m, d: __import__("casest.interop", fromlist=["x"]).estimator_function(m, 0), "N must be a positive"),
    (lambda m, d: __import__("casest.interop", fromlist=["x"]).add_to_opti(None, m, d), "needs a casadi.Opti"),
    (lambda m, d: __import__("casest.filters", fromlist=["x"]).rts_smoother("x"), "takes the FilterResult"),
    (lambda m, d: casest.load_model_file(3), "a model file is named by a bundled name or a path"),
])
def test_bad_arguments_of_public_entry_points_raise_casest_errors(clean, call, message):
    """Each raised a NumPy, CasADi or Python error before (TypeError, RuntimeError, AttributeError)."""
    model, data, _ = clean
    with pytest.raises(casest.CasestError, match=message):
        call(model, data)


def test_equal_bounds_hold_the_parameter_instead_of_crashing_stage_1():
    """Parameter("b", 0.05, 0.05), the fix casest's rank-deficiency message recommends, crashed the
    sweep's neighbour search (NaN coordinates); it is now held at that value, with a note."""
    import casadi as ca

    a, b, c, eta = (ca.SX.sym(n) for n in ("a", "b", "c", "eta"))
    model = casest.Model([casest.Parameter("a", -2, 2), casest.Parameter("b", 0.05, 0.05),
                          casest.Parameter("c", 0, 1)], [casest.Signal("eta")], {"z": a * ca.cos(eta * (1 + b) + c)})
    x = np.linspace(0, 6, 200)
    z = 1.3 * np.cos(x * 1.05 + 0.4) + 0.01 * np.random.default_rng(0).standard_normal(200)
    est = casest.estimate(model, casest.Dataset(model, {"eta": x, "z": z}))
    assert est.values["b"] == 0.05 and "fixed (not estimated): b = 0.05" in est.notes[0]
    assert abs(est.values["c"] - 0.4) < 3 * est.stds["c"]


@pytest.mark.parametrize("kind", ["input", "output"])
def test_a_delay_bound_far_beyond_the_record_is_refused_at_once(kind):
    """A delay bound of 1000 s at 20 ms built 50 005 lag columns (544 s, 2.4 GB); now a ModelError
    names the bound and the largest one supported, before anything is built."""
    import casadi as ca

    x, u, k, tau = (ca.SX.sym(n) for n in ("x", "u", "k", "tau"))
    with pytest.raises(casest.ModelError, match=r"needs 50002 lagged samples .* at most 9\.96 s here"):
        casest.DynamicModel([casest.Parameter("k", 0.1, 5.0, 1.0), casest.Parameter("tau", 0.0, 1000.0, 0.1)],
                            [casest.State("x", 0.0)], ["u"], rhs={"x": k * u - x}, outputs={"y": x},
                            delays={"u" if kind == "input" else "y": "tau"}, sample_time=0.02)


def _saved_array(data: dict, field: str) -> dict:
    """A saved array's shape and values (result_schema: ``{"array": {"shape", "values"}}``)."""
    return data[field]["array"]


@pytest.mark.parametrize("edit, message", [
    (lambda d: _saved_array(d, "std").update(values=[-abs(v) for v in _saved_array(d, "std")["values"]]),
     "is negative"),
    (lambda d: _saved_array(d, "theta")["values"].__setitem__(0, None), "missing or not finite"),
    (lambda d: _saved_array(d, "R")["values"].__setitem__(0, -1.0), "must be positive and finite"),
    (lambda d: _saved_array(d, "theta")["values"].__setitem__(1, 10.0), "outside its bounds"),
    (lambda d: _saved_array(d, "theta").update(values=_saved_array(d, "theta")["values"][:2], shape=[2]),
     "has shape (2,)"),
    (lambda d: d.update(parameter_names={"tuple": d["parameter_names"]["tuple"][:3]}), "has shape"),
])
def test_an_edited_result_file_is_refused(tmp_path, edit, message):
    """A result file edited to a negative std, a null value, R = -1, theta outside its bounds, or a
    partial theta or parameter list loaded and said "trust it"; now each names the field."""
    import json

    scalar2 = casest.load_model_file("scalar2")
    est = casest.estimate(scalar2.model(), scalar2.simulate(0))
    data = json.loads(est.to_json())
    edit(data)
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(data))
    with pytest.raises(casest.ResultFileError) as info:
        casest.Estimate.from_json(path)
    assert message in str(info.value)


def test_the_same_record_twice_is_not_two_experiments():
    """The same CSV given twice was two experiments: the std shrank by sqrt(2) and it said "trust it"."""
    scalar2 = casest.load_model_file("scalar2")
    data = scalar2.simulate(0)
    with pytest.raises(casest.DataError, match="experiments 'e1' and 'e2' are the same record"):
        casest.estimate(scalar2.model(), [data, data])
    with pytest.raises(casest.DataError, match="experiments 'a' and 'b' are the same record"):
        casest.estimate(scalar2.model(), {"a": data, "b": data.subset(slice(None))})


def test_recursive_ml_refuses_what_would_turn_it_into_nan():
    """RecursiveML returned NaN parameters for a 1e200 output or a NaN signal, and ran on another
    model's data; each is now a DataError naming the problem."""
    from casest.recursive import RecursiveML

    scalar2, magnetometer = casest.load_model_file("scalar2"), casest.load_model_file("magnetometer")
    model, data = scalar2.model(), scalar2.simulate(0)
    rml = RecursiveML(model, model.nominal, [0.01])
    with pytest.raises(casest.DataError, match="'z' reaches 1e\\+200"):
        rml.update(data.signals[:5], np.full((5, 1), 1e200))
    with pytest.raises(casest.DataError, match="signals hold NaN or infinite values at rows \\[2\\]"):
        rml.update(np.where(np.arange(5)[:, None] == 2, np.nan, data.signals[:5]), data.outputs[:5])
    with pytest.raises(casest.DataError, match="do not match model"):
        rml.run(magnetometer.simulate(0))
    assert np.all(np.isfinite(rml.theta)) and rml.n_samples == 0


def test_negative_or_nan_process_noise_is_refused():
    """rts_smoother(process_noise=...) and continuous_to_discrete returned negative or NaN noise
    matrices for a negative or NaN input."""
    from casest.filters import KalmanFilter, continuous_to_discrete, rts_smoother

    A, B, G = np.array([[0.0, 1.0], [-2.0, -0.5]]), np.array([[0.0], [1.0]]), np.eye(2)
    for Qc, message in ((-np.eye(2), "Qc must be positive semi-definite"), (np.full((2, 2), np.nan), "Qc has non-finite")):
        with pytest.raises(casest.OptionError, match=message):
            continuous_to_discrete(A, B, G, Qc, 0.1)
    with pytest.raises(casest.OptionError, match="A has non-finite"):
        continuous_to_discrete(np.full((2, 2), np.nan), B, G, np.eye(2), 0.1)
    Phi, Psi, Qd = continuous_to_discrete(A, B, G, 0.01 * np.eye(2), 0.1)
    kf = KalmanFilter(Phi, np.array([[1.0, 0.0]]), Qd, np.array([[0.01]]), np.zeros(2), np.eye(2), Psi=Psi)
    rng = np.random.default_rng(0)
    result = kf.filter(rng.standard_normal((50, 1)), np.zeros((50, 1)))
    for Q, message in ((-Qd, "positive semi-definite"), (np.full((2, 2), np.nan), "non-finite")):
        with pytest.raises(casest.OptionError, match=f"process noise Q \\(process_noise\\).*{message}"):
            rts_smoother(result, process_noise=Q)


@pytest.mark.parametrize("delays, sample_time, message", [
    ("symbol", 0.02, r"the delay of input 'u' is a CasADi expression \(tau\); .* write delays=\{'u': 'tau'\}"),
    ({"u": "tau"}, 0.0, "sample_time must be the record's sampling interval, a positive number of seconds; got 0.0"),
    ({"u": "tau"}, float("nan"), "positive number of seconds; got nan"),
])
def test_delay_declarations_get_messages_that_name_the_fix(delays, sample_time, message):
    """delays={"u": tau} (the symbol) was answered "not declared", sample_time=0 or NaN with "give sample_time"."""
    import casadi as ca

    x, u, k, tau = (ca.SX.sym(n) for n in ("x", "u", "k", "tau"))
    delays = {"u": tau} if delays == "symbol" else delays
    with pytest.raises(casest.ModelError, match=message):
        casest.DynamicModel([casest.Parameter("k", 0.1, 5.0, 1.0), casest.Parameter("tau", 0.0, 0.2, 0.1)],
                            [casest.State("x", 0.0)], ["u"], rhs={"x": k * u - x}, outputs={"y": x}, delays=delays,
                            sample_time=sample_time)


def test_a_model_file_that_exits_at_import_is_named(tmp_path, capsys):
    """A model file calling sys.exit(0) at import made `casest solve` print nothing and exit 0."""
    path = tmp_path / "exiting.py"
    path.write_text("import sys\nsys.exit(0)\n")
    with pytest.raises(casest.ModelFileError, match=r"called sys.exit\(0\) while it was imported"):
        casest.load_model_file(str(path))
    from casest.apps.cli import main

    assert main(["solve", str(path)]) != 0
    assert "called sys.exit(0)" in capsys.readouterr().err


def test_an_output_file_that_cannot_be_replaced_is_refused_before_the_solve(tmp_path, monkeypatch, capsys):
    """An existing --json that could not be replaced was found after the solve, and the error named
    a hidden temporary file. (As root every file is writable: the refusal is simulated.)"""
    import os

    from casest.apps.cli import main
    from casest.data import atomic_write_text

    target = tmp_path / "estimate.json"
    target.write_text("{}")
    real_replace = os.replace

    def refuse(src, dst):
        if os.fspath(dst) == os.fspath(target):
            raise PermissionError(1, "Operation not permitted")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", refuse)
    with pytest.raises(OSError) as info:
        atomic_write_text(target, "new")
    assert str(target) in str(info.value) and ".tmp_" not in str(info.value)
    monkeypatch.setattr(os, "replace", real_replace)
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if os.fspath(p) == str(target) else real_access(p, mode))
    assert main(["solve", "scalar1", "--json", str(target)]) != 0
    err = capsys.readouterr()
    assert "exists and cannot be replaced" in err.err and "[[Parameters]]" not in err.out  # refused before solving


@pytest.mark.parametrize("change, message", [
    ({"estimate": {"k": 0.04}}, r"estimate names \['k'\], which are not parameters of the model \['c', 'L'\]"),
    ({"estimate": {}}, "at least one"),
    ({"theta": [0.1, 1.0]}, "theta must map every parameter name"),
    ({"theta": {"c": float("nan"), "L": 1.0}}, r"theta of \['c'\] is not finite"),
    ({"parameter_noise": {"c": -1.0}}, r"parameter_noise of \['c'\] must be a finite intensity"),
    ({"iterate": True}, r"joint_filter takes the options .* not \['iterate'\]"),
])
def test_joint_filter_names_the_argument(change, message):
    """joint_filter raised a bare KeyError for an unknown parameter, named the wrong argument for a
    negative parameter noise, and a TypeError for a misspelt option."""
    from casest.recursive.joint import joint_filter

    import casadi as ca

    ang, rate, c, L = (ca.SX.sym(n) for n in ("ang", "rate", "c", "L"))
    model = casest.DynamicModel([casest.Parameter("c", 0.0, 2.0, 0.3), casest.Parameter("L", 0.5, 2.0, 1.0)],
                                [casest.State("ang", 1.0), casest.State("rate", 0.0)], [],
                                rhs={"ang": rate, "rate": -9.81 / L * ca.sin(ang) - c * rate},
                                outputs={"px": L * ca.sin(ang)})
    arguments = dict(theta={"c": 0.1, "L": 1.0}, estimate={"c": 0.04}, process_noise={"rate": 0.05}, R=[0.0025],
                     P0=np.eye(2) * 1e-4)
    arguments.update(change)
    with pytest.raises(casest.OptionError, match=message):
        joint_filter(model, **arguments)


def test_a_huge_noise_is_named_not_blamed_on_p_equal_to_zero():
    """A measurement noise of 1e200 overflowed the filter, and the message blamed P = 0."""
    from casest.filters import KalmanFilter

    C = np.array([[1.0, 0.0]])
    for name, kwargs in (("R", dict(R=np.array([[1e200]]), Q=np.eye(2) * 1e-3)),
                         ("Q", dict(R=np.array([[0.01]]), Q=np.eye(2) * 1e200))):
        with pytest.raises(casest.OptionError, match=f"{name} reaches 1e\\+200: the filter's products of it overflow"):
            KalmanFilter(np.eye(2), C, x0=np.zeros(2), P0=np.eye(2), **kwargs)


def test_a_short_record_can_be_filtered_but_not_estimated():
    """A 1-sample record was refused for a filter by the estimator's parameter-count rule; built
    with for_estimation=False it is filtered, and an estimate from it is still refused."""
    import casadi as ca

    from casest.filters import ExtendedKalmanFilter

    x, k = ca.SX.sym("x"), ca.SX.sym("k")
    model = casest.DynamicModel([casest.Parameter("k", 0.1, 5.0, 1.0)], [casest.State("x", 1.0)], [],
                                rhs={"x": -k * x}, outputs={"y": x})
    columns = {"t": np.array([0.0]), "y": np.array([1.02])}
    with pytest.raises(casest.DataError, match="build it with for_estimation=False"):
        model.dataset(columns)
    short = model.dataset(columns, for_estimation=False)
    result = ExtendedKalmanFilter(model, {"k": 1.0}, {"x": 0.01}, [0.01], [[0.1]]).filter(short)
    assert result.x_filtered.shape == (1, 1) and abs(result.x_filtered[0, 0] - 1.0) < 0.05
    with pytest.raises(casest.DataError, match="need at least"):
        casest.estimate(model, short)


def test_a_lookup_table_evaluated_outside_its_grid_is_named():
    """A record that drives a table beyond its grid was estimated without a word (the table
    extrapolates its end segment); a table built with casest.lookup_table is now checked and the
    samples beyond it counted in a note, and a raw casadi.interpolant is named as unchecked."""
    from casest.status import NoteCode

    grid = np.linspace(-0.5, 0.5, 21)
    alpha, k = ca.SX.sym("alpha"), ca.SX.sym("k")
    a = np.linspace(-0.4, 0.7, 200)
    for table, expected in ((casest.lookup_table("CL", [grid], np.sin(grid)), f"at {int(np.sum(a > 0.5))} of 200"),
                            (ca.interpolant("CLraw", "linear", [grid], np.sin(grid)), "casest cannot see the grid")):
        model = casest.Model([casest.Parameter("k", 0.1, 5.0, 1.0)], ["alpha"], {"y": k * table(alpha)})
        z = 1.3 * np.sin(np.clip(a, -0.5, 0.5)) + 0.01 * np.random.default_rng(0).standard_normal(a.size)
        est = casest.estimate(model, casest.Dataset.from_arrays(model, a[:, None], z[:, None]))
        assert any(n.code is NoteCode.TABLE_RANGE and expected in n for n in est.notes), est.notes


def test_a_discretisation_that_overflows_is_named():
    """G = 1e200 made continuous_to_discrete return a NaN Qd without a word (found by
    `python3 scripts/campaigns/fuzz_inputs.py --apis --examples 300`)."""
    from casest.filters import continuous_to_discrete

    with pytest.raises(casest.OptionError, match="the discretised Qd overflows double precision"):
        continuous_to_discrete(np.eye(2) * 0.1, np.full((2, 1), 0.3), np.diag([1e200, 0.1]), np.eye(2) * 0.1, 0.1)
