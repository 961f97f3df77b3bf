"""Recursive maximum likelihood (summary Eq. 5.10-5.13) against the batch ML estimate.

Truth: casest's batch ML estimate (two-stage, exact Hessian std) of the same 5000 samples of
scalar 2 (paper Eq. 33, noise std 0.3, seed 3). The samples arrive in a random order (fixed
seed), as a stationary excitation would deliver them (in the file's order eta sweeps 1 to 10
once, and the early samples would see only a part of the range). After all of them the
recursive estimate of every parameter lies within 0.5 batch std of the batch estimate, R
within 5 %, and its own std within 10 % of the batch std.
"""

import numpy as np
import pytest

import casest
from casest.recursive.ml import RecursiveML


def test_recursive_ml_reaches_the_batch_ml_estimate():
    module = casest.load_model_file("scalar2")
    model = module.model()
    data = module.simulate(3, n=5000)
    batch = casest.estimate(model, data)
    order = np.random.default_rng(0).permutation(data.n_samples)
    rml = RecursiveML(model, model.vector(module.TRUTH) + np.array([0.1, 0.02, 0.05, -0.1]), [0.5])
    history = rml.run(casest.Dataset.from_arrays(model, data.signals[order], data.outputs[order]))
    assert history.shape == (5000, 4) and rml.n_samples == 5000
    assert np.all(np.abs(rml.theta - batch.theta) < 0.5 * batch.std), (rml.theta - batch.theta) / batch.std
    assert rml.R[0] == pytest.approx(batch.R[0], rel=0.05)
    np.testing.assert_allclose(rml.std, batch.std, rtol=0.1)


def test_an_indefinite_information_gives_nan_std_not_zero():
    """Truth by construction: an information matrix with a negative eigenvalue is no covariance's
    inverse, so no parameter has a std (a std of 0 would claim certainty); a positive definite
    one gives the square roots of its inverse's diagonal."""
    from casest.estimation.uncertainty import std_from_covariance, std_from_information

    model = casest.load_model_file("scalar2").model()
    rml = RecursiveML(model, model.nominal, [0.5])
    n = rml.information.shape[0]
    rml.information = np.diag(np.r_[-1.0, np.ones(n - 1)])
    assert np.all(np.isnan(rml.std))
    rml.information = np.diag(np.arange(1.0, n + 1))
    np.testing.assert_allclose(rml.std, 1 / np.sqrt(np.arange(1.0, n + 1))[:model.n_parameters])
    np.testing.assert_array_equal(std_from_covariance(np.diag([4.0, -1e-18, np.nan])), [2.0, np.nan, np.nan])
    assert np.all(np.isnan(std_from_information(np.zeros((2, 2)))))


def test_recursive_ml_checks_its_start():
    model = casest.load_model_file("scalar2").model()
    with pytest.raises(casest.OptionError, match="R0 must hold 1 positive finite noise variances"):
        RecursiveML(model, model.nominal, [0.0])
    with pytest.raises(casest.OptionError, match="casest.DynamicModel"):
        RecursiveML(object(), [0.0], [1.0])


@pytest.mark.slow
def test_recursive_ml_on_a_dynamic_model_reaches_the_batch_output_error_estimate():
    """Truth: casest's batch output-error ML of the same 20001-sample record (short-period model,
    random binary elevator input, seed 0). Recursive ML starts 10 % off in every parameter and at
    4x the noise variances, in time order, with forgetting lambda(0) = 0.9, r = 0.995; after the
    record every parameter lies within 0.5 batch std, R within 5 % and the std within 15 %."""
    module = casest.load_model_file("short_period")
    model, data = module.model(), module.simulate_random(seed=0, duration=400.0)
    batch = casest.estimate(model, data)
    assert batch.success
    R0 = 4.0 * np.array([module.NOISE_STD[n] for n in model.output_names]) ** 2
    rml = RecursiveML(model, {k: 1.1 * v for k, v in module.TRUTH.items()}, R0, forgetting=0.9,
                      forgetting_rate=0.995)
    rml.run(data, block=1)
    assert np.all(np.abs(rml.theta - batch.theta) < 0.5 * batch.std), (rml.theta - batch.theta) / batch.std
    np.testing.assert_allclose(rml.R, batch.R, rtol=0.05)
    np.testing.assert_allclose(rml.std, batch.std, rtol=0.15)


def test_recursive_ml_on_a_dynamic_model_needs_time_order_and_a_state():
    module = casest.load_model_file("short_period")
    model, data = module.model(), module.simulate(seed=0)
    rml = RecursiveML(model, module.TRUTH, [1e-4, 1e-4, 0.02])
    with pytest.raises(casest.OptionError, match="state is not set"):
        rml.update(data.signals[:2], data.outputs[:2])
    rml.run(casest.Dataset.from_arrays(model, data.signals[:50], data.outputs[:50]))
    with pytest.raises(casest.OptionError, match="time order"):
        rml.update(data.signals[10:12], data.outputs[10:12])
