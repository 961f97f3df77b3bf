"""The frequency domain's residual verdict: flatness and coherence tests, colored-residual std,
a diagnosed delay and its refit (casest.frequency.spectral_checks, delay_diagnosis, refit).

Truths, on the short-period record of models/short_period.py (20 s at 50 Hz, 40 frequencies
0.05-2 Hz, the model file's noise std), simulated here with fixed seeds:
- white noise: the right model, so no test of the family may fail (the family's level is 1e-3);
- AR(1) noise of coefficient 0.9: the right model with coloured noise (its spectrum falls by a
  factor 6.6 across the band), so the verdict is coloured noise (seed 1 is one of the records
  where the test detects it: the campaign's rate is below 100 %) and the colored-residual std
  exceed the white-noise ones;
- the elevator reaching the aircraft 3 samples (60 ms) after the recorded one: a delay, so the
  residuals are coherent with the input, the diagnosis names the delay within 2 of its std of 3
  samples, and the refit estimates it within 3 std with residuals that no longer depend on it.
The rates over 400 seeds of each case are in scripts/campaigns/residual_verdict.py --parts frequency.
"""

import numpy as np
import pytest
from scipy.signal import lfilter

import casest
from casest.status import CheckCode, DiagnosisCode, ResidualCode, TrustCode

SP = casest.load_model_file("short_period")
MODEL = SP.model()
BAND = 2 * np.pi * np.arange(1, 41) / SP.DURATION


def record(seed: int, rho: float = 0.0, late_samples: int = 0) -> casest.Dataset:
    """The short-period record with AR(rho) noise, the input late by ``late_samples``."""
    t = np.arange(int(SP.DURATION * SP.RATE) + 1) / SP.RATE
    exact = SP.model(substeps=8)
    zeros = np.zeros_like(t)
    seen = SP.elevator(t - late_samples / SP.RATE)
    _, clean = exact.simulate(dict(SP.TRUTH), exact.dataset({"t": t, "delta_e": seen,
                                                             **{n: zeros for n in MODEL.output_names}}))
    rng = np.random.default_rng([seed, 66])
    noise = lfilter([np.sqrt(1 - rho**2)], [1, -rho], rng.standard_normal(clean.shape), axis=0)
    z = clean + noise * np.array([SP.NOISE_STD[n] for n in MODEL.output_names])
    return MODEL.dataset({"t": t, "delta_e": SP.elevator(t), **{n: z[:, j] for j, n in enumerate(MODEL.output_names)}})


def test_white_noise_passes_the_family_and_the_std_stay_white():
    fd = casest.frequency_domain_estimate(MODEL, record(0), BAND)
    codes = {c.code for c in fd.residual_checks}
    assert codes == {CheckCode.FLATNESS, CheckCode.COHERENCE}
    assert len(fd.residual_checks) == 1 + 3 * 2  # flatness of every output; per output the input and the fit
    assert all(c.passed for c in fd.residual_checks)
    assert fd.conclusion()[0] is TrustCode.LOCAL and not fd.colored and fd.diagnosis is None
    np.testing.assert_array_equal(fd.std, fd.std_white)


def test_coloured_noise_is_told_apart_and_the_std_grow():
    fd = casest.frequency_domain_estimate(MODEL, record(1, rho=0.9), BAND)
    code, reason = fd.conclusion()
    assert code is TrustCode.COLOURED_NOISE, reason
    assert fd.colored and "colored-residual std" in fd.report()
    acting = [i for i, n in enumerate(fd.parameter_names) if n not in fd.held]
    assert np.all(fd.std[acting] > fd.std_white[acting])
    assert not any(c.code is CheckCode.COHERENCE for c in fd.residual_checks if not c.passed)


def test_a_late_input_is_diagnosed_as_a_delay_and_refitted(tmp_path):
    data = record(2, late_samples=3)
    fd = casest.frequency_domain_estimate(MODEL, data, BAND)
    assert fd.conclusion()[0] is TrustCode.MODEL_ERROR
    d = fd.diagnosis
    assert d is not None and d.code is DiagnosisCode.LAG and d.signals == ("delta_e",)
    assert abs(d.value - 3.0) < 2 * d.std, (d.value, d.std)
    assert d.verdict_after is not ResidualCode.DEPENDENT
    refit = casest.refit(fd, MODEL, data)
    assert refit.parameter == "delay_delta_e"
    assert abs(refit.value - 3.0) < 3 * refit.std, (refit.value, refit.std)
    assert np.all(refit.rms_after < refit.rms_before)
    assert refit.estimate.conclusion()[0] is not TrustCode.MODEL_ERROR
    # the figure's residuals are the fit's: their mean square per channel is the settled S_j
    _, V, channels = casest.frequency.frequency_residuals(fd, MODEL, data)
    np.testing.assert_allclose(np.mean(np.abs(V) ** 2, axis=0), fd.spectra, rtol=1e-6)
    pytest.importorskip("matplotlib")
    fig = casest.frequency.spectral_figure(refit.estimate, MODEL, data)
    assert len(fig.axes) == 2 * len(channels) and fig.axes[1].get_title() == "residual response to the inputs"
    assert "<img" in fd.to_html(model=MODEL, data=data)
    path = tmp_path / "fd.json"
    fd.to_json(path)
    back = casest.FrequencyEstimate.from_json(path)
    assert back.diagnosis.describe() == d.describe()
    assert [c.to_dict() for c in back.residual_checks] == [c.to_dict() for c in fd.residual_checks]
    assert back.conclusion() == fd.conclusion()


def test_a_delay_is_estimated_as_a_parameter_and_bad_delays_are_refused():
    data = record(3, late_samples=3)
    fd = casest.frequency_domain_estimate(MODEL, data, BAND, delay=["delta_e"])
    i = fd.parameter_names.index("delay_delta_e")
    assert abs(fd.theta[i] - 3 / SP.RATE) < 3 * fd.std[i]
    with pytest.raises(casest.OptionError, match=r"not inputs of the model"):
        casest.frequency_domain_estimate(MODEL, data, BAND, delay=["elevator"])
    with pytest.raises(casest.OptionError, match=r"outside the delay's bounds"):
        casest.frequency_domain_estimate(MODEL, data, BAND, delay=["delta_e"], delay_start=10.0)


def test_frequencies_closer_than_the_resolution_run_no_tests():
    fd = casest.frequency_domain_estimate(MODEL, record(0), BAND[:20] / 2)
    assert fd.residual_checks == () and any("residual tests are not run" in n for n in fd.notes)


def test_a_file_without_the_tests_still_loads():
    """A FrequencyEstimate written before the residual tests (no such fields) loads as untested."""
    fd = casest.frequency_domain_estimate(MODEL, record(0), BAND[:20])
    old = {k: v for k, v in fd.to_dict().items()
           if k not in ("std_white", "colored", "residual_checks", "diagnosis", "sample_interval", "delayed")}
    back = casest.FrequencyEstimate.from_dict(old)
    assert back.residual_checks == () and back.diagnosis is None and not back.colored
    np.testing.assert_array_equal(back.theta, fd.theta)
    assert back.conclusion()[0] is TrustCode.LOCAL
