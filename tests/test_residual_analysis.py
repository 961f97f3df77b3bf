"""Residual analysis of records in time: autocorrelation with its band, colored-residual std.

Truths: white measurement noise (the short-period model file's simulation) leaves the
residuals white, so about 5 % of the lags fall outside the 95 % band and the colored std
equals the ML std (ratio within 0.7-1.3); process noise that output error cannot follow
(the closed-loop oscillator of test_filters, turbulence on the rate) leaves residuals
correlated in time: most lags outside the band and colored std well above the ML std.
"""

import os
import subprocess
import sys

import numpy as np
import pytest

import casest
from test_filters import loop_model, loop_record

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="module")
def white():
    mf = casest.load_model_file(os.path.join(REPO, "models", "short_period.py"))
    return casest.estimate(mf.model(), mf.simulate(0))


def test_white_residuals_stay_in_the_band_and_keep_the_ml_std(white):
    analysis = white.residual_analysis
    assert analysis is not None and analysis.parameter_names == white.parameter_names
    assert np.all(analysis.outside < 0.15)
    finite = np.isfinite(analysis.ratio)
    assert finite.all() and 0.7 < np.median(analysis.ratio) < 1.3
    np.testing.assert_allclose(analysis.autocorrelation[:, 0], 1.0)


def test_turbulence_shows_as_correlated_residuals_and_larger_std():
    model = loop_model()
    est = casest.estimate(model, loop_record(model, 0, N=1000))  # output error on a record with process noise
    analysis = est.residual_analysis
    assert np.max(analysis.outside) > 0.3
    assert np.median(analysis.ratio[np.isfinite(analysis.ratio)]) > 1.5
    assert "[[Residual analysis]]" in est.report() and "correlated in time" in est.report()


def test_analysis_survives_the_json_round_trip(white, tmp_path):
    back = casest.Estimate.from_json(white.to_json(tmp_path / "est.json"))
    for key in ("autocorrelation", "band", "outside", "colored_std", "ratio"):
        np.testing.assert_array_equal(getattr(back.residual_analysis, key), getattr(white.residual_analysis, key))
    assert back.residual_analysis.max_lag == white.residual_analysis.max_lag


def test_static_estimates_have_a_record_order_analysis_and_keep_the_ml_std_when_white():
    """A static record is analysed in its own order (the colored-residual std exist for a verdict of
    coloured noise); with white residuals the ML std are the ones reported."""
    mf = casest.load_model_file(os.path.join(REPO, "models", "scalar1.py"))
    est = casest.estimate(mf.model(), mf.simulate(0))
    assert est.residual_analysis is not None and est.std_choice().kind == "ml"


def test_solve_writes_the_output_fit_figure(tmp_path):
    pytest.importorskip("matplotlib")
    figure = tmp_path / "fit.png"
    out = subprocess.run([sys.executable, "-m", "casest", "solve", "short_period", "--quick", "--figure", str(figure)],
                         capture_output=True, text=True, cwd=REPO)
    assert out.returncode in (0, 4), out.stderr
    assert figure.stat().st_size > 10000


def test_colored_std_equals_the_explicit_toeplitz_sandwich(white):
    """Truth: (J'WJ)^-1 J'W C W J (J'WJ)^-1 with C built as a dense Toeplitz matrix per channel."""
    from scipy.linalg import toeplitz

    mf = casest.load_model_file(os.path.join(REPO, "models", "short_period.py"))
    model, data = mf.model(), mf.simulate(0)
    problem = casest.Problem(model, data)
    theta, R = white.theta, white.R
    L, N, ny = white.residual_analysis.max_lag, data.n_samples, model.n_outputs
    J = problem.jacobian(theta).reshape(N, ny, -1)
    r = data.outputs - problem.predict(theta)
    M, middle = 0.0, 0.0
    for j in range(ny):
        column = np.zeros(N)
        column[:L + 1] = [r[:N - lag, j] @ r[lag:, j] / N for lag in range(L + 1)]
        M = M + J[:, j].T @ J[:, j] / R[j]
        middle = middle + J[:, j].T @ toeplitz(column) @ J[:, j] / R[j] ** 2
    Minv = np.linalg.inv(M)
    np.testing.assert_allclose(white.residual_analysis.colored_std, np.sqrt(np.diag(Minv @ middle @ Minv)), rtol=1e-8)
