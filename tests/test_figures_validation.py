"""Figures from the Python API (fit, residuals, convergence, proof of match), the validation
metrics on a held-out record, and the convergence history saved with the estimate. Truth of
the metrics: computed by hand on a 3 x 2 case; the oscillator's data simulated with a fixed
seed."""

import casadi as ca
import numpy as np
import pytest

import casest
from casest.estimation.figures import save_figure, validation_figure

P = casest.Parameter


def test_theil_inequality_by_hand():
    z = np.array([[1.0, 2.0], [2.0, 0.0], [3.0, 1.0]])
    y = np.array([[1.5, 2.0], [2.0, 1.0], [2.0, 1.0]])
    # column 0: rms error sqrt(1.25 / 3), rms z sqrt(14 / 3), rms y sqrt(10.25 / 3)
    expected0 = np.sqrt(1.25 / 3) / (np.sqrt(14 / 3) + np.sqrt(10.25 / 3))
    expected1 = np.sqrt(1.0 / 3) / (np.sqrt(5 / 3) + np.sqrt(6 / 3))
    np.testing.assert_allclose(casest.theil_inequality(z, y), [expected0, expected1], rtol=1e-14)
    assert casest.theil_inequality(z, z)[0] == 0.0
    np.testing.assert_allclose(casest.theil_inequality(z, -z), [1.0, 1.0])  # no match at all


@pytest.fixture(scope="module")
def oscillator():
    x, v, u, a, k, c, d = (ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "c", "d"))
    model = casest.DynamicModel(
        [P("a", 0.05, 2.0, 0.5), P("k", 0.5, 8.0, 2.0), P("c", -5.0, 5.0, 1.0), P("d", -5.0, 5.0, 0.0)],
        [casest.State("x", 0.0), casest.State("v", 0.0)], ["u"],
        rhs={"x": v, "v": -k * x - a * v + u}, outputs={"y1": c * x + d, "y2": v})
    records = []
    for seed in range(3):
        t = np.arange(400) * 0.02
        drive = np.sin(0.7 * t + seed) + 0.5 * np.sin(2.3 * t)
        blank = model.dataset({"t": t, "u": drive, "y1": 0 * t, "y2": 0 * t})
        _, clean = model.simulate({"a": 0.3, "k": 3.0, "c": 1.7, "d": -0.4}, blank)
        noisy = clean + np.random.default_rng(seed).normal(0, [0.05, 0.02], clean.shape)
        records.append(model.dataset({"t": t, "u": drive, "y1": noisy[:, 0], "y2": noisy[:, 1]}))
    return model, records, casest.estimate(model, records[:2])


def test_validation_on_a_held_out_record(oscillator):
    model, records, est = oscillator
    val = est.validate(model, records[2])
    predicted = model.predict_data(est.values, records[2])
    residual = records[2].outputs - predicted
    np.testing.assert_allclose(val.rms_error, np.sqrt(np.mean(residual**2, axis=0)), rtol=1e-12)
    np.testing.assert_allclose(val.rms_error, [0.05, 0.02], rtol=0.15)  # the simulated noise std
    assert np.all(val.theil < 0.1) and np.all(val.r_squared > 0.98)
    assert "Theil U" in val.report()


def test_convergence_history_is_recorded_and_saved(oscillator, tmp_path):
    model, _, est = oscillator
    history = est.convergence
    assert history is not None and history.theta.shape[1] == model.n_parameters
    np.testing.assert_array_equal(history.theta[-1], est.theta)
    assert np.all(np.diff(history.cost) <= 1e-9 * np.abs(history.cost[:-1]))  # accepted steps lower the cost
    np.testing.assert_allclose(history.std[-1], est.std, rtol=0.05)  # Gauss-Newton's std against the Hessian's
    again = casest.Estimate.from_json(est.to_json(tmp_path / "est.json"))
    np.testing.assert_array_equal(again.convergence.theta, history.theta)


def test_figures_from_the_python_api(oscillator, tmp_path):
    pytest.importorskip("matplotlib")
    model, records, est = oscillator
    fit = est.plot_fit(model, records[:2])
    assert len(fit.axes) == 3 * 2  # two outputs and the autocorrelation row, per manoeuvre
    residuals = est.plot_residuals(model, records[:2])
    convergence = est.plot_convergence()
    assert len([ax for ax in convergence.axes if ax.get_visible() and ax.lines]) == model.n_parameters + 1
    match = validation_figure(est.validate(model, records[2]))
    correlation = est.plot_correlation()
    assert len(correlation.axes[0].texts) == model.n_parameters * (model.n_parameters - 1)
    for name, fig in {"fit": fit, "residuals": residuals, "convergence": convergence, "match": match,
                      "correlation": correlation}.items():
        path = save_figure(fig, tmp_path / f"{name}.png")
        assert (tmp_path / f"{name}.png").stat().st_size > 10_000, path


def test_a_static_estimate_records_ipopt_iterates_when_asked():
    """Pitot calibration (static, IPOPT in reduced then full mode): no history by default; with
    record_iterates the history ends at the estimate, with the Hessian's std within 10 %."""
    pitot = casest.load_model_file("pitot5hole")
    model, data = pitot.model(), pitot.simulate(0, t_end=600.0)
    est = casest.estimate(model, data)
    with pytest.raises(casest.OptionError, match="record_iterates=True"):
        est.plot_convergence()
    recorded = casest.estimate(model, data, solver_settings=casest.SolverSettings(record_iterates=True))
    np.testing.assert_allclose(recorded.theta, est.theta, rtol=1e-9, atol=1e-12)  # recording changes nothing
    history = recorded.convergence
    assert history.theta.shape[0] >= 2 and history.parameter_names == model.parameter_names
    np.testing.assert_allclose(history.theta[-1], recorded.theta, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(history.cost[-1], recorded.cost, rtol=1e-9)
    np.testing.assert_allclose(history.std[-1], recorded.std, rtol=0.1)
    pytest.importorskip("matplotlib")
    assert recorded.plot_convergence().axes and est.plot_fit(model, data).axes


def test_std_choice_keeps_the_ml_std_for_white_residuals(oscillator):
    """White simulated noise: the whiteness tests pass and the ML std stands (the AP2 parts, whose
    residuals are correlated in time, report the colored-residual std: tests/test_ampyx.py)."""
    _, _, est = oscillator
    choice = est.std_choice()
    assert choice.kind == "ml" and "pass the whiteness tests" in choice.reason
    np.testing.assert_array_equal(choice.std, est.std)
    assert "std to report: ML" in est.report()
