"""Bad inputs to the newer APIs get a casest error that names the problem.

Truths: the inputs built here (a NaN at a known row, a text column).
"""

import json

import casadi as ca
import numpy as np
import pytest

import casest


@pytest.mark.parametrize("columns, message", [
    ({"x": np.r_[np.arange(5.0), np.nan, np.arange(4.0)], "z": np.arange(10.0)},
     r"column 'x' holds NaN or infinite values at rows \[5\]"),
    ({"x": ["a"] * 10, "z": np.arange(10.0)}, "column 'x' must be an array of numbers"),
    ({"x": np.arange(10.0), "z": ["b"] * 10}, r"y \(column 'z'\) must be an array of numbers"),
])
def test_regression_names_the_row_and_the_column(columns, message):
    x = ca.SX.sym("x")
    with pytest.raises(casest.DataError, match=message):
        casest.regress("z", {"c": 1, "x": x}, columns)


def test_known_noise_takes_a_mapping():
    with pytest.raises(casest.ModelError, match=r"KnownNoise takes a mapping of output name to noise std"):
        casest.KnownNoise([0.09])


@pytest.mark.parametrize("bad, message", [
    (1e200, "their squares overflow double precision"),
    (np.inf, "holds infinite values at rows"),
])
def test_the_kalman_filter_refuses_what_is_neither_a_measurement_nor_missing(bad, message):
    from casest.filters.kalman import KalmanFilter

    kf = KalmanFilter(Phi=[[1.0]], C=[[1.0]], Q=[[0.01]], R=[[0.1]], x0=[0.0], P0=[[1.0]])
    with pytest.raises(casest.DataError, match=message):
        kf.update([bad])
    for compiled in (True, False):
        with pytest.raises(casest.DataError, match=message):
            kf.filter(np.array([[0.1], [bad], [0.2]]), compiled=compiled)
    x, _ = kf.update([np.nan])  # NaN is a channel not measured: skipped
    assert np.isfinite(x).all()


@pytest.mark.parametrize("options", [{"alpha": 1e6}, {"kappa": 1e12}, {"alpha": 0.0}, {"beta": -1.0},
                                     {"alpha": float("nan")}])
def test_the_unscented_filter_refuses_sigma_parameters_out_of_range(options):
    m = casest.load_model_file("short_period")
    model = m.model()
    R = [m.NOISE_STD[n] ** 2 for n in model.output_names]
    with pytest.raises(casest.OptionError, match=r"sigma points need 0 < alpha <= 1"):
        casest.UnscentedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-6, **options)


def test_the_unscented_filter_takes_a_state_known_exactly():
    """P0 = 0 with R > 0 (the EKF takes it): the sigma points start at the mean, the filter follows
    the record (innovations of the size of the measurement noise)."""
    m = casest.load_model_file("short_period")
    model, data = m.model(), m.simulate(seed=0)
    R = [m.NOISE_STD[n] ** 2 for n in model.output_names]
    result = casest.UnscentedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, np.zeros((2, 2))).filter(data)
    assert np.all(np.isfinite(result.x_filtered))
    rms = np.sqrt(np.mean(result.innovation**2, axis=0))
    assert np.all(rms < 5 * np.sqrt(R)), (rms, np.sqrt(R))


def test_older_unclear_cases_are_named():
    """A state's initial value of the wrong type; a prediction a negative number of steps ahead; a
    task size that is not a whole number; a forgetting rate outside [0, 1); an information of zero."""
    with pytest.raises(casest.ModelError, match="initial value of state 'x' must be a number"):
        casest.State("x", None)
    with pytest.raises(casest.OptionError, match="task_size must be a whole number"):
        casest.SweepSettings(task_size=1.5)
    from casest.filters.kalman import KalmanFilter
    from casest.recursive.ml import RecursiveML

    kf = KalmanFilter(Phi=[[1.0]], C=[[1.0]], Q=[[0.01]], R=[[0.1]], x0=[0.0], P0=[[1.0]])
    with pytest.raises(casest.OptionError, match="steps must be a whole number of samples >= 1"):
        kf.predict_ahead(-3)
    m = casest.load_model_file("scalar2").model()
    with pytest.raises(casest.OptionError, match="forgetting_rate must lie in"):
        RecursiveML(m, m.nominal, [0.1], forgetting_rate=1.5)
    with pytest.raises(casest.OptionError, match=r"forgetting \(lambda\(0\)\) must lie in"):
        RecursiveML(m, m.nominal, [0.1], forgetting=-1)
    with pytest.raises(casest.OptionError, match="information0 must be positive definite"):
        RecursiveML(m, m.nominal, [0.1], information0=np.zeros(m.n_parameters + 1))


def test_the_command_line_refuses_a_value_given_twice(capsys):
    from casest.apps.cli import main

    assert main(["solve", "scalar2", "--quick", "--fix", "a=1", "--fix", "a=2"]) == 2
    assert "--fix gives ['a'] more than once" in capsys.readouterr().err
    assert main(["solve", "scalar2", "--quick", "--noise", "known:z=0.3,z=0.4"]) == 2
    assert "gives the std of ['z'] more than once" in capsys.readouterr().err


@pytest.mark.parametrize("field, value, message", [
    ("success", "yes", "field 'success' is 'yes'"),
    ("n_samples", -5, "field 'n_samples' is -5"),
    ("n_iterations", -3, "field 'n_iterations' is -3"),
])
def test_an_edited_result_file_of_the_wrong_types_is_refused(tmp_path, field, value, message):
    import json

    m = casest.load_model_file("scalar1")
    est = casest.estimate(m.model(), m.simulate(seed=0))
    data = json.loads(est.to_json())
    data[field] = value
    with pytest.raises(casest.ResultFileError, match=message):
        casest.Estimate.from_json(json.dumps(data))


def test_an_edited_spread_is_refused():
    """A correlation of 5, a std of 0, a covariance entry of -1: none of them loads."""
    import copy

    from casest.estimation.result_files import check_loaded_estimate

    m = casest.load_model_file("scalar1")
    est = casest.estimate(m.model(), m.simulate(seed=0))
    check_loaded_estimate(est)
    for edit, message in ((lambda e: e.correlation.__setitem__((0, 1), 5.0), "a correlation reaches 5"),
                          (lambda e: e.std.__setitem__(0, 0.0), "is 0, which no estimate"),
                          (lambda e: e.covariance.__setitem__((0, 0), -1.0), "not the std squared")):
        edited = copy.deepcopy(est)
        edit(edited)
        with pytest.raises(casest.ResultFileError, match=message):
            check_loaded_estimate(edited)


@pytest.mark.parametrize("index, message", [
    (None, "the frame has only row numbers"),
    ("nat", r"missing stamps \(NaT or NaN\) at rows \[2\]"),
    ("repeated", r"repeats stamps at rows \[2\]"),
])
def test_a_data_frames_index_that_is_not_a_time_is_named(index, message):
    pandas = pytest.importorskip("pandas")
    m = casest.load_model_file("short_period")
    model, data = m.model(), m.simulate(0)
    columns = {n: data.column(n)[:20] for n in list(data.signal_names) + list(data.output_names) if n != "t"}
    frame = pandas.DataFrame(columns)  # the default RangeIndex: row numbers, not a time
    if index == "nat":
        frame.index = pandas.to_timedelta(np.r_[0.0, 0.02, np.nan, np.arange(3, 20) * 0.02], unit="s")
    elif index == "repeated":
        frame.index = pandas.Index(np.r_[0.0, 0.02, 0.02, np.arange(3, 20) * 0.02], name="t")
    with pytest.raises(casest.DataError, match=message):
        casest.Dataset.from_dataframe(model, frame)


def test_units_for_a_label_not_in_the_frame_are_refused():
    pandas = pytest.importorskip("pandas")
    m = casest.load_model_file("scalar2")
    data = m.simulate(seed=0)
    frame = pandas.DataFrame({n: data.column(n) for n in list(data.signal_names) + list(data.output_names)})
    with pytest.raises(casest.DataError, match=r"units= names \['zz'\], which the frame does not hold"):
        casest.Dataset.from_dataframe(m.model(), frame, units={"zz": "m"})


def test_profile_intervals_check_what_they_start_from():
    from casest.two_stage.profile import profile_intervals

    m = casest.load_model_file("scalar2")
    model, data = m.model(), m.simulate(0)
    problem = casest.Problem(model, data)
    est = casest.estimate(problem)
    with pytest.raises(casest.OptionError, match="theta_hat must be finite"):
        profile_intervals(problem, np.full(4, np.nan), est.R)
    with pytest.raises(casest.OptionError, match="R_hat must hold 1 positive finite noise variances"):
        profile_intervals(problem, est.theta, [-0.09])
    with pytest.raises(casest.OptionError, match=r"\['a'\] are held fixed in this problem"):
        profile_intervals(casest.Problem(model, data, fixed={"a": 0.0}), est.theta[1:], est.R, names=["a"])
    other = casest.load_model_file("scalar1")
    with pytest.raises(casest.OptionError, match="give the estimate of this problem"):
        profile_intervals(problem, casest.estimate(other.model(), other.simulate(0)), est.R)


def test_a_result_file_from_a_newer_casest_says_so():
    import json

    m = casest.load_model_file("scalar1")
    data = json.loads(casest.estimate(m.model(), m.simulate(seed=0)).to_json())
    data["format"] = "casest.Estimate/7"
    with pytest.raises(casest.ResultFileError, match="written by a newer casest"):
        casest.Estimate.from_json(json.dumps(data))
    data["format"] = "something.else/1"
    with pytest.raises(casest.ResultFileError, match="not a casest estimate"):
        casest.Estimate.from_json(json.dumps(data))


def test_filters_and_smoothers_name_a_wrong_argument():
    from casest.filters.ekf import ExtendedKalmanFilter, rts_smoother
    from casest.filters.smoothing import single_stage_smoother

    m = casest.load_model_file("short_period")
    model, data = m.model(), m.simulate(0)
    ekf = ExtendedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, [m.NOISE_STD[n] ** 2 for n in model.output_names],
                               np.eye(2) * 1e-6)
    result = ekf.filter(data)
    with pytest.raises(casest.OptionError, match="a FilterResult is a filter pass already"):
        ekf.filter(result)
    with pytest.raises(casest.OptionError, match="not a mapping of state names"):
        rts_smoother(result, process_noise={"q": 1e-4})
    for k in (1.7, float("nan")):
        with pytest.raises(casest.OptionError, match="needs a whole sample index k"):
            single_stage_smoother(result, k, np.eye(2))


def test_a_csv_with_one_column_is_told_what_it_lacks(tmp_path):
    """A comment line above the header, a file with one of the model's columns only, and a delimiter
    casest does not know: each its own cause (the delimiter was blamed for all three)."""
    m = casest.load_model_file("scalar2")
    model = m.model()
    rows = ["eta,z"] + [f"{e},{z}" for e, z in zip(np.linspace(0, 1, 20), np.linspace(1, 2, 20))]
    cases = {"comment.csv": (["# flight 12"] + rows, "is a comment"),
             "one.csv": ([r.split(",")[0] for r in rows], r"holds only the column 'eta'.*\['z'\] are missing"),
             "pipes.csv": ([r.replace(",", "|") for r in rows], "pass the delimiter")}
    for name, (lines, message) in cases.items():
        path = tmp_path / name
        path.write_text("\n".join(lines) + "\n")
        with pytest.raises(casest.DataError, match=message):
            casest.Dataset.from_csv(model, str(path))


def test_design_experiment_names_a_candidate_of_another_model_and_a_bad_prior():
    """A candidate record with another model's columns, a prior information of the wrong size or
    with NaN: a casest error naming it (before: no error, a NumPy ValueError, a LinAlgError)."""
    scalar2, pitot = casest.load_model_file("scalar2"), casest.load_model_file("pitot5hole")
    model, data = scalar2.model(), scalar2.simulate(0)
    candidates = {f"b{k}": data.subset(np.arange(20 * k, 20 * k + 20)) for k in range(5)}
    with pytest.raises(casest.DataError, match="candidate 'other' is not a record of model 'scalar2'"):
        casest.design_experiment(model, {"other": pitot.simulate(0)}, scalar2.TRUTH, [0.09], budget=1e6)
    for prior, message in [(np.eye(3), r"prior_information must have shape \(4, 4\), got \(3, 3\)"),
                           (np.full((4, 4), np.nan), "prior_information has non-finite entries")]:
        with pytest.raises(casest.OptionError, match=message):
            casest.design_experiment(model, candidates, scalar2.TRUTH, [0.09], budget=100.0, prior_information=prior)


@pytest.mark.parametrize("kind", ["ExtendedKalmanFilter", "UnscentedKalmanFilter"])
def test_a_filter_step_names_a_sample_of_the_wrong_size(kind):
    """One sample of 2 values for a model with 3 outputs (before: NumPy's broadcast error)."""
    sp = casest.load_model_file("short_period")
    model = sp.model()
    R = [sp.NOISE_STD[n] ** 2 for n in model.output_names]
    flt = getattr(casest, kind)(model, sp.TRUTH, {"q": 1e-4}, R, np.eye(2), x0=np.zeros(2))
    with pytest.raises(casest.OptionError, match=r"y must hold one sample of the 3 outputs \['alpha_m'"):
        flt.update([1.0, 2.0], np.zeros(1))
    with pytest.raises(casest.OptionError, match="u must hold one sample of the 1 inputs"):
        flt.update([1.0, 2.0, 3.0], np.zeros(3))


@pytest.mark.parametrize("line, problem", [
    ('{"run": 2}', "no methods"),
    ('{"run": 2, "seed": 2, "methods": {"proposed": {"theta": "x"}}}', "proposed.theta is not a list of numbers"),
    ("garbage{", "not JSON"),
])
def test_a_malformed_run_record_is_dropped_with_a_warning_and_run_again(tmp_path, line, problem):
    """A campaign's journal with a line that is not a run record (before: 'internal error, a bug
    in casest' on resume): the line is named and dropped, the run done again."""
    from casest.apps.montecarlo import CampaignConfig, run_campaign

    config = CampaignConfig(model=str(casest.load_model_file("scalar1").__file__), reference_starts=2)
    run_campaign(config, 2, str(tmp_path), progress=False)
    with open(tmp_path / "runs.jsonl", "a") as fh:
        fh.write(line + "\n")
    with pytest.warns(RuntimeWarning, match=rf"line 3: not a run record \({problem}\)"):
        summary = run_campaign(config, 3, str(tmp_path), progress=False)
    assert summary["runs"] == 3
    runs = sorted(json.loads(text)["run"] for text in (tmp_path / "runs.jsonl").read_text().splitlines())
    assert runs == [0, 1, 2]


def test_recursive_ml_names_samples_of_the_wrong_shape_or_none():
    """Found by the API fuzz campaign (seed 7): five rows of no columns ended in NumPy's reshape
    error; now the argument, its shape and the model's columns are named, and no rows is refused."""
    from casest.recursive import RecursiveML

    model = casest.load_model_file("scalar2").model()
    rml = RecursiveML(model, model.nominal, [0.01])
    with pytest.raises(casest.DataError, match=r"signals must have shape \(m, 1\), one column each of \['eta'\]"):
        rml.update(np.zeros((5, 0)), np.zeros((5, 0)))
    with pytest.raises(casest.DataError, match="no samples given"):
        rml.update(np.zeros((0, 1)), np.zeros((0, 1)))


def test_the_smoother_and_the_savitzky_golay_filter_name_what_the_fuzz_campaign_found():
    """API fuzz campaign, seed 11: a transition of 1e-200 on a state with no process noise left
    P(k+1|k) singular (the compiled smoother returned NaN, the NumPy one 'Singular matrix'); a
    sample interval of 1e200 s overflowed SciPy's derivative scale (OverflowError)."""
    from casest.data import savitzky_golay
    from casest.filters import KalmanFilter, rts_smoother

    kf = KalmanFilter(Phi=np.diag([1e-200, 0.1]), C=[[0.3, 0.3]], Q=np.diag([0.0, 0.1]), R=[[0.1]], x0=np.zeros(2),
                      P0=np.diag([0.1, 0.1]))
    result = kf.filter(np.full((20, 1), 0.3))
    for compiled in (True, False):
        with pytest.raises(casest.OptionError, match=r"P\(k\+1\|k\) at sample 1 is not positive definite"):
            rts_smoother(result, compiled=compiled)
    with pytest.raises(casest.DataError, match="dt = 1e\\+200 s to the power 2 leaves double precision"):
        savitzky_golay(np.full(40, 0.3), 1e200, 5, 2, 2)


@pytest.mark.parametrize("value", [True, 2.0, "3", 0, -1, None])
def test_a_count_is_a_whole_number_wherever_it_is_given(value):
    """One check of a count (checks.whole_number) at every entry point that takes one: a bool, a float,
    text, zero or a negative number is refused with the argument's name (SolverSettings.shooting_interval
    and DynamicModel's substeps took True as 1 before)."""
    from casest.checks import whole_number

    with pytest.raises(casest.OptionError, match=r"steps must be a whole number of samples >= 1, got"):
        whole_number(value, "steps must be a whole number of samples >= 1")
    with pytest.raises(casest.OptionError, match="shooting_interval must be a positive integer"):
        casest.SolverSettings(shooting_interval=value)
    assert whole_number(3, "n") == 3 and isinstance(whole_number(np.int64(3), "n"), int)
