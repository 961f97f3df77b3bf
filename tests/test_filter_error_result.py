"""Filter-error ML in the result family: finite std for unbounded parameters, codes, JSON, report.

Truth: the closed-loop oscillator of test_filters (simulated with process noise, fixed seed);
estimates within 3 std of the truth; the JSON round trip is lossless (array equality).
"""

import casadi as ca
import numpy as np
import pytest

import casest
from casest.status import Outcome, StdReason
from test_filters import LOOP_TRUTH, loop_record


def unbounded_loop_model() -> casest.DynamicModel:
    """The closed-loop oscillator of test_filters with no parameter bounds."""
    x, v, u, a, k, b = (ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "b"))
    P = casest.Parameter
    return casest.DynamicModel([P("a", nominal=1.0, scale=1.0), P("k", nominal=2.0, scale=1.0),
                                P("b", nominal=1.5, scale=1.0, unit="1/s^2")],
                               [casest.State("x", 0.0), casest.State("v", 0.0)], ["u"],
                               {"x": v, "v": -k * x - a * v + b * u}, {"y1": x, "y2": v}, name="oscillator_loop",
                               substeps=2, input_hold="zoh")


@pytest.fixture(scope="module")
def unbounded():
    model = unbounded_loop_model()
    return model, casest.filter_error_estimate(model, loop_record(model, 0, N=600), {"v": 0.1})


def test_unbounded_parameters_get_finite_std(unbounded):
    model, fe = unbounded
    assert np.all(np.isinf(model.lower_bounds)) and np.all(np.isinf(model.upper_bounds))
    assert fe.success and fe.outcome is Outcome.CONVERGED
    assert fe.active_bounds == [None, None, None] and fe.std_reason_codes == [None, None, None]
    assert np.all(np.isfinite(fe.std)) and np.all(fe.std > 0)
    truth = model.vector(LOOP_TRUTH)
    assert np.all(np.abs(fe.theta - truth) < 3 * fe.std), (fe.theta - truth) / fe.std


def test_json_round_trip_and_report(unbounded, tmp_path):
    _, fe = unbounded
    path = tmp_path / "fe.json"
    fe.to_json(path)
    back = casest.FilterErrorEstimate.from_json(path)
    for key, value in fe.__dict__.items():
        if key == "filter":
            assert back.filter is None
        elif isinstance(value, np.ndarray):
            np.testing.assert_array_equal(getattr(back, key), value)
        else:
            assert getattr(back, key) == value, key
    report = fe.report()
    assert "b = " in report and "+/-" in report and "1/s^2" in report
    assert "[[Conclusion]] local solve: converged from the given start" in report
    with pytest.raises(casest.ResultFileError):
        casest.FilterErrorEstimate.from_json('{"format": "something else"}')


def test_a_parameter_on_its_bound_has_a_reason_code():
    x, v, u, a, k, b = (ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "b"))
    P = casest.Parameter
    model = casest.DynamicModel([P("a", 0.0, 3.0, 1.0), P("k", 0.5, 2.5, 2.0), P("b", 0.1, 5.0, 1.5)],
                                [casest.State("x", 0.0), casest.State("v", 0.0)], ["u"],
                                {"x": v, "v": -k * x - a * v + b * u}, {"y1": x, "y2": v}, substeps=2,
                                input_hold="zoh")
    fe = casest.filter_error_estimate(model, loop_record(model, 0, N=400), {"v": 0.1})  # the true k = 4 lies above 2.5
    i = model.parameter_names.index("k")
    assert fe.active_bounds[i] == "upper" and fe.std_reason_codes[i] is StdReason.ACTIVE_BOUND
    assert np.isnan(fe.std[i]) and not fe.trust()[0]


def test_data_units_the_model_does_not_declare_make_a_caution(unbounded):
    """The same record, with y1's file unit undeclared by the model: a note with its code,
    and the conclusion is a caution that names it."""
    from casest.status import NoteCode, TrustCode

    model, fe = unbounded
    data = loop_record(model, 0, N=600)
    data.undeclared_units = {"y1": "deg"}  # what Dataset.from_csv records for a header 'y1 [deg]'
    flagged = casest.filter_error_estimate(model, data, {"v": 0.1})
    assert fe.conclusion()[0] is TrustCode.LOCAL
    assert any(n.code is NoteCode.UNITS and "y1 [deg]" in n for n in flagged.notes)
    code, reason = flagged.conclusion()
    assert code is TrustCode.CAUTION and "units the model does not declare" in reason


def test_a_problem_brings_its_record_fixed_parameters_and_known_noise():
    """filter_error_estimate(problem, None, ...) is the estimate of the problem's model (its fixed
    parameters substituted) on its record with its known R: the same numbers as the model, data
    and R given apart (array equality), and a full R refused with the fix."""
    from test_filters import LOOP_NOISE, loop_model

    model = loop_model()
    data = loop_record(model, 3, N=300)
    R = np.full(2, LOOP_NOISE ** 2)
    direct = casest.filter_error_estimate(model.with_fixed({"b": LOOP_TRUTH["b"]}), data, {"v": 0.1}, R=R)
    problem = casest.Problem(model, data, noise=casest.KnownNoise(dict(zip(model.output_names, np.sqrt(R)))),
                             fixed={"b": LOOP_TRUTH["b"]})
    through = casest.filter_error_estimate(problem, None, {"v": 0.1})
    np.testing.assert_array_equal(through.theta, direct.theta)
    assert through.parameter_names == ("a", "k") and not through.R_estimated
    with pytest.raises(casest.OptionError, match="DiagonalNoise"):
        casest.filter_error_estimate(casest.Problem(model, data, noise=casest.CorrelatedNoise()), None, {"v": 0.1})
    with pytest.raises(casest.OptionError, match="give R once"):
        casest.filter_error_estimate(problem, None, {"v": 0.1}, R=R)


def test_the_time_varying_record_is_the_filters_pass(unbounded):
    """What the estimate holds of its filter: the innovations and their std are the EKF pass's, the
    predictions are the measurements less the innovations, and the final gain is the Kalman gain
    of the last sample (P(N|N) = (I - K C) P(N|N-1) with C = I for this model, to 1e-10)."""
    model, fe = unbounded
    record, run = fe.predictions, fe.filter
    np.testing.assert_array_equal(fe.innovations, record.measured - record.predicted)
    np.testing.assert_allclose(fe.innovations, run.innovation, rtol=0, atol=1e-12)
    np.testing.assert_allclose(record.innovation_std, np.sqrt(np.einsum("kjj->kj", run.innovation_covariance)))
    K, P = fe.gain, run.P_predicted[-1]
    np.testing.assert_allclose(run.P_filtered[-1], (np.eye(2) - K) @ P, rtol=1e-10, atol=1e-14)
    assert fe.kc_diagonal == dict(zip(model.state_names, np.diag(K).tolist()))
    assert record.gain_at == "the last sample" and record.time.shape == (600,)


def test_process_noise_as_f_with_its_std_correlations_and_cpu_time(unbounded):
    """F = sqrt(q) with std(q) / (2 F) (first-order propagation of q = F^2); the correlation matrix of
    every decision variable from the covariance; CPU and wall time, in the report too."""
    _, fe = unbounded
    F, F_std = fe.process_noise_distribution, fe.process_noise_distribution_std
    assert F["v"] ** 2 == pytest.approx(fe.process_noise["v"], rel=1e-14)
    assert F_std["v"] == pytest.approx(fe.process_noise_std["v"] / (2 * F["v"]), rel=1e-14)
    names, corr = fe.decision_names, fe.correlation
    assert names == ("a", "k", "b", "q[v]", "R[y1]", "R[y2]") and corr.shape == (6, 6)
    np.testing.assert_allclose(np.diag(corr), 1.0, rtol=1e-12)
    np.testing.assert_allclose(corr, corr.T, rtol=1e-12)
    assert 0 < fe.cpu_seconds < 10 * fe.seconds + 1
    report = fe.report()
    for section in ("[[Kalman gain]]", "[[Correlations]]", "s wall", "s CPU", "v: F = "):
        assert section in report, section


def test_the_page_draws_the_filter_not_a_free_simulation(unbounded, monkeypatch, tmp_path):
    """The HTML page of a filter-error estimate draws its one-step predictions and innovations (its
    own record), never the model's free simulation, even with the model and data given; it lists
    the fit statistics of the report; the record survives the JSON round trip."""
    pytest.importorskip("matplotlib")
    import casest.estimation.figures as figures

    model, fe = unbounded

    def no_simulation(*args, **kwargs):
        raise AssertionError("a filter-error page drew the free simulation")

    monkeypatch.setattr(figures, "fit_figure", no_simulation)
    monkeypatch.setattr(figures, "residuals_figure", no_simulation)
    page = fe.to_html(tmp_path / "fe.html", model=model, data=loop_record(model, 0, N=600))
    assert "id='fit_statistics'" in page and "s CPU" in page and page.count("data:image/png") >= 2
    fig = fe.plot_fit()
    assert len(fig.axes) == 3 * model.n_outputs
    back = casest.FilterErrorEstimate.from_json(fe.to_json())
    assert back.predictions == fe.predictions and back.cpu_seconds == fe.cpu_seconds
