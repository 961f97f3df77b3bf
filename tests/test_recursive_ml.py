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
from casest.state.recursive_ml import RecursiveML


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


def test_recursive_ml_checks_its_start():
    model = casest.load_model_file("scalar2").model()
    with pytest.raises(casest.OptionError, match="R0 must be positive"):
        RecursiveML(model, model.nominal, [0.0])
    with pytest.raises(casest.OptionError, match="static casest.Model"):
        RecursiveML(object(), [0.0], [1.0])
