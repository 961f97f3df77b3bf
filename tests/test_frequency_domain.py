"""Frequency-domain equation error and output error (casest.frequency_domain_estimate) and the
recursive Fourier transform.

Truths: the time-domain output-error estimate of the same simulated short-period record
(models/short_period.py: 3-2-1-1 and doublet, white noise), within 0.5 of the frequency-domain
std; the simulation's true parameters within 3 std; the frequency-domain std against the
Monte-Carlo spread of 30 records (seeds 0-29) within 40 %; the batch finite Fourier transform
written here as a double loop, to 1e-12, for the recursive one.
"""

import numpy as np
import pytest

import casest
from casest.errors import OptionError

SP = casest.load_model_file("short_period")
MODEL = SP.model()
BAND = 2 * np.pi * np.arange(1, 41) / SP.DURATION  # 0.05-2 Hz on the record's frequency grid
STATES = {"alpha": "alpha_m", "q": "q_m"}
DERIVATIVES = ["Z_alpha", "Z_delta", "M_alpha", "M_q", "M_delta"]


def test_output_error_equals_the_time_domain_estimate_within_its_std():
    data = SP.simulate(0)
    fd = casest.frequency_domain_estimate(MODEL, data, BAND)
    td = casest.estimate(MODEL, data)
    assert fd.success and fd.held == ("b_alpha", "b_q")
    idx = [MODEL.parameter_names.index(n) for n in DERIVATIVES]
    assert np.all(np.abs(fd.theta[idx] - td.theta[idx]) < 0.5 * fd.std[idx])
    truth = np.array([SP.TRUTH[n] for n in DERIVATIVES])
    assert np.all(np.abs(fd.theta[idx] - truth) < 3 * fd.std[idx])


def test_equation_error_recovers_the_truth_from_the_measured_states():
    fd = casest.frequency_domain_estimate(MODEL, SP.simulate(1), BAND, method="equation-error", states=STATES)
    idx = [MODEL.parameter_names.index(n) for n in DERIVATIVES]
    truth = np.array([SP.TRUTH[n] for n in DERIVATIVES])
    assert fd.success and np.all(np.abs(fd.theta[idx] - truth) < 3 * fd.std[idx])


@pytest.mark.slow
def test_the_std_match_the_monte_carlo_spread():
    idx = [MODEL.parameter_names.index(n) for n in DERIVATIVES]
    runs = [casest.frequency_domain_estimate(MODEL, SP.simulate(seed), BAND) for seed in range(30)]
    spread = np.std([r.theta[idx] for r in runs], axis=0, ddof=1)
    ratio = np.mean([r.std[idx] for r in runs], axis=0) / spread
    assert np.all(np.abs(ratio - 1) < 0.4), ratio


def test_the_recursive_transform_equals_the_batch_one():
    data = SP.simulate(0)
    t, Y = data.signals[:, 0], data.outputs
    online = casest.RecursiveFourierTransform(BAND[:10], t[1] - t[0], Y.shape[1])
    for k in range(len(t)):
        online.update(Y[k])
    dt = t[1] - t[0]
    batch = np.array([[sum(Y[k, j] * np.exp(-1j * w * t[k]) * dt for k in range(len(t))) for j in range(Y.shape[1])]
                      for w in BAND[:10]])
    np.testing.assert_allclose(online.transform, batch, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(casest.fourier_transform(Y, t, BAND[:10]), batch, rtol=1e-12, atol=1e-12)


def test_mistakes_are_named():
    data = SP.simulate(0)
    with pytest.raises(OptionError, match="positive angular frequencies"):
        casest.frequency_domain_estimate(MODEL, data, [0.0, 1.0])
    with pytest.raises(OptionError, match=r"every state measured: give states=.*\['alpha', 'q'\]"):
        casest.frequency_domain_estimate(MODEL, data, BAND, method="equation-error")
    with pytest.raises(OptionError, match="'output-error' or 'equation-error'"):
        casest.frequency_domain_estimate(MODEL, data, BAND, method="frequency")
    fine = casest.frequency_domain_estimate(MODEL, data, BAND[:10] / 2)
    assert any("correlated" in n for n in fine.notes)


def test_the_frequency_domain_takes_the_shared_solver_settings_and_codes_its_notes(monkeypatch):
    """SolverSettings reach the frequency domain's IPOPT (a one-iteration budget ends unconverged,
    said by a NOT_VERIFIED note); every note carries a code; a wrong settings type is refused."""
    import casadi as ca

    mf = casest.load_model_file("short_period")
    model, data = mf.model(), mf.simulate(0)
    w = np.linspace(0.5, 10.0, 20)
    seen = []
    original = ca.nlpsol
    monkeypatch.setattr(ca, "nlpsol", lambda *a, **k: seen.append(a[-1]) or original(*a, **k))
    fe = casest.frequency_domain_estimate(model, data, w, settings=casest.SolverSettings(max_iter=1))
    assert seen and seen[0]["ipopt.max_iter"] == 1
    assert not fe.success and any(n.code is casest.status.NoteCode.NOT_VERIFIED for n in fe.notes)
    assert all(isinstance(n.code, casest.status.NoteCode) for n in fe.notes)
    with pytest.raises(casest.OptionError, match="settings must be a casest.SolverSettings"):
        casest.frequency_domain_estimate(model, data, w, settings={"tol": 1e-6})


@pytest.mark.parametrize("band, message", [
    (np.array([]), "frequencies is empty"),
    (np.linspace(1.0, 400.0, 30), "Nyquist frequency"),
    (np.array([2.0]), r"1 frequencies give \d+ real residuals for \d+ parameters and \d+ residual spectra"),
])
def test_a_band_the_record_cannot_carry_is_refused(band, message):
    """Truth: the record's sampling (Nyquist pi / dt) and the count of real residuals a band gives
    (two per frequency and output) against the parameters acting in it."""
    with pytest.raises(OptionError, match=message):
        casest.frequency_domain_estimate(MODEL, SP.simulate(0), band)


def test_a_nonlinear_model_is_said_to_be_linearised():
    """The pendulum (sin of its angle): the estimate carries a FREQUENCIES note naming the
    linearisation; the linear short period does not."""
    from test_compiled_filters import THETA, pendulum

    model = pendulum()
    t = np.arange(400) * 0.05
    torque = 0.5 * np.sin(1.3 * t)
    _, Y = model.simulate(THETA, model.dataset({"t": t, "torque": torque, "px": 0 * t, "py": 0 * t}))
    data = model.dataset({"t": t, "torque": torque, "px": Y[:, 0], "py": Y[:, 1]})
    fd = casest.frequency_domain_estimate(model, data, 2 * np.pi * np.arange(1, 30) / 20.0)
    assert any(n.code is casest.status.NoteCode.FREQUENCIES and "nonlinear" in str(n) for n in fd.notes)
    linear = casest.frequency_domain_estimate(MODEL, SP.simulate(0), BAND)
    assert not any("nonlinear" in str(n) for n in linear.notes)


def test_a_problem_brings_its_record_and_fixed_parameters():
    """frequency_domain_estimate(problem, None, band) estimates the problem's model (its fixed
    parameter substituted) on its record: the same numbers as the fixed model and the record given
    apart (array equality); a known noise is refused with the fix."""
    data = SP.simulate(2)
    name = MODEL.parameter_names[0]
    fixed = {name: SP.TRUTH[name]}
    direct = casest.frequency_domain_estimate(MODEL.with_fixed(fixed), data, BAND)
    through = casest.frequency_domain_estimate(casest.Problem(MODEL, data, fixed=fixed), None, BAND)
    np.testing.assert_array_equal(through.theta, direct.theta)
    assert name not in through.parameter_names
    known = casest.KnownNoise({o: 0.1 for o in MODEL.output_names})
    with pytest.raises(casest.OptionError, match="DiagonalNoise"):
        casest.frequency_domain_estimate(casest.Problem(MODEL, data, noise=known), None, BAND)
