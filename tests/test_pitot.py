"""5-hole Pitot-tube model (paper Sec. IV) and its flight simulator."""

import numpy as np
import pytest

import casest
from casest.apps.sim.flight import MANEUVERS, simulate_trajectory

from conftest import model_file


@pytest.fixture(scope="module")
def pitot():
    return model_file("pitot5hole")


def test_separator_finds_paper_partition(pitot):
    """Paper Eq. 42: xi1 = [lambda_V b_V W_N W_E W_D], xi2 = [lambda_alpha b_alpha lambda_beta b_beta eps_a]."""
    part = casest.separate(pitot.model())
    assert set(part.linear) == {"lambda_V", "b_V", "W_N", "W_E", "W_D"}
    assert set(part.nonlinear) == {"lambda_alpha", "b_alpha", "lambda_beta", "b_beta", "eps_a"}
    assert part.alternatives == ()


def _euler_dot(angles, rates):
    phi, theta = angles[0], angles[1]
    p, q, r = rates
    return np.array([
        p + (q * np.sin(phi) + r * np.cos(phi)) * np.tan(theta),
        q * np.cos(phi) - r * np.sin(phi),
        (q * np.sin(phi) + r * np.cos(phi)) / np.cos(theta),
    ])


def test_body_rates_integrate_to_the_attitude():
    """RK4 on the Euler kinematics, driven by the simulated body rates, over 60 s with both wind circles."""
    traj = simulate_trajectory(seed=3, t_start=380.0, t_end=440.0, rate=50.0)
    t, rates = traj.time, traj.body_rates
    angles = traj.euler[0].copy()
    dt = t[1] - t[0]
    worst = 0.0
    for k in range(t.size - 1):
        mid = 0.5 * (rates[k] + rates[k + 1])  # rates are smooth: midpoint by averaging
        k1 = _euler_dot(angles, rates[k])
        k2 = _euler_dot(angles + 0.5 * dt * k1, mid)
        k3 = _euler_dot(angles + 0.5 * dt * k2, mid)
        k4 = _euler_dot(angles + dt * k3, rates[k + 1])
        angles = angles + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        worst = max(worst, np.max(np.abs(angles - traj.euler[k + 1])))
    assert worst < 1e-3


def test_flight_has_the_table5_manoeuvres():
    traj = simulate_trajectory(seed=0)
    for name, t0, t1, _ in MANEUVERS:
        assert traj.time[0] <= t0 and t1 <= traj.time[-1], name
    for t0, t1 in [(384.0, 408.2), (411.0, 438.3)]:  # wind circles: full heading sweeps
        m = (traj.time >= t0) & (traj.time <= t1)
        assert np.ptp(np.unwrap(traj.euler[m, 2])) >= 2 * np.pi
        assert 20 <= np.degrees(np.max(np.abs(traj.euler[m, 0]))) <= 30
    assert 12 <= traj.airspeed.min() and traj.airspeed.max() <= 25


def test_noise_free_flight_is_reproduced_by_the_model(pitot):
    data = pitot.simulate(1, noise=False)
    pred = pitot.model().predict(pitot.TRUTH, data.signals)
    np.testing.assert_allclose(pred, data.outputs, atol=1e-9, rtol=0)
    v5 = pitot.calibrated_airspeed(data, pitot.TRUTH)
    np.testing.assert_allclose(v5, data.column("V_ref"), atol=1e-9)


def test_csv_has_named_columns_with_units(tmp_path, pitot):
    data = pitot.simulate(0).subset(slice(0, 50))
    path = tmp_path / "flight.csv"
    data.to_csv(path, units=pitot.UNITS)
    header = path.read_text().splitlines()[0].split(",")
    assert "V_N [m/s]" in header and "P_alpha [Pa]" in header and "time [s]" in header
    back = casest.Dataset.from_csv(pitot.model(), path)
    np.testing.assert_array_equal(back.outputs, data.outputs)


def test_one_flight_estimate_within_three_std_of_truth(pitot):
    """Simulated truth; every 4th sample (12.5 Hz) keeps the test quick."""
    data = pitot.simulate(11)
    stage1, stage2 = pitot.stage_data(data)
    stage1, stage2 = stage1.subset(slice(None, None, 4)), stage2.subset(slice(None, None, 4))
    est = casest.estimate(pitot.model(), stage2, stage1_data=stage1, sweep_settings=pitot.SWEEP_SETTINGS)
    assert est.success
    truth = pitot.model().vector(pitot.TRUTH)
    assert np.all(np.abs(est.theta - truth) < 3 * est.std), (est.theta - truth) / est.std
