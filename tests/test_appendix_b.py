"""Appendix B models: magnetometer calibration and aircraft data compatibility (simulated truth)."""

import numpy as np
import pytest

import casest

from conftest import model_file


@pytest.fixture(scope="module")
def magnetometer():
    return model_file("magnetometer")


@pytest.fixture(scope="module")
def compatibility():
    return model_file("data_compatibility")


def test_magnetometer_partition_and_its_ties(magnetometer):
    """{lambda, n}, {alpha, n} and {eta, n} are equally large; the paper's split (Eq. B3) comes first."""
    part = casest.separate(magnetometer.model())
    assert part.linear == ("lambda_x", "lambda_y", "lambda_z", "n_x", "n_y", "n_z")
    assert set(map(frozenset, part.alternatives)) == {
        frozenset({"n_x", "n_y", "n_z", "alpha_xy", "alpha_xz", "alpha_yz"}),
        frozenset({"n_x", "n_y", "n_z", "eta_x", "eta_y", "eta_z"}),
    }


@pytest.mark.parametrize("seed", [0, 1])
def test_magnetometer_recovers_truth_within_three_std(magnetometer, seed):
    model = magnetometer.model()
    est = casest.estimate(model, magnetometer.simulate(seed))
    assert est.success
    truth = model.vector(magnetometer.TRUTH)
    assert np.all(np.abs(est.theta - truth) < 3 * est.std), (est.theta - truth) / est.std
    np.testing.assert_allclose(np.sqrt(est.R), magnetometer.NOISE_STD, rtol=0.1)


def test_data_compatibility_is_all_linear_with_known_states(compatibility):
    part = casest.separate(compatibility.model_states_known())
    assert part.nonlinear == () and len(part.linear) == 12


def test_data_compatibility_split_is_eq_b8_with_the_ode(compatibility):
    """Paper Eq. B8: the twelve output scale factors and biases linear, the six IMU biases swept."""
    part = casest.separate(compatibility.model())
    assert set(part.linear) == set(compatibility.TRUTH_OUTPUTS)
    assert set(part.nonlinear) == set(compatibility.TRUTH_IMU)


@pytest.mark.parametrize("seed", [0, 1])
def test_data_compatibility_recovers_truth_within_three_std(compatibility, seed):
    model = compatibility.model_states_known()
    est = casest.estimate(model, compatibility.simulate_states_known(seed))
    assert est.success and est.landscape.verdict == "linear"
    truth = model.vector(compatibility.TRUTH_STATES_KNOWN)
    assert np.all(np.abs(est.theta - truth) < 3 * est.std), (est.theta - truth) / est.std
