"""Readers for real logs as published: the bundled Ampyx AP2 MATLAB record (nested structs,
3 x N and 3 x 3 x N fields) through Dataset.from_mat by struct paths, and the bundled PX4
ULog through Dataset.from_ulog (topics logged at different, irregular rates aligned onto one
time base). Truth: the same fields read by hand with scipy.io.loadmat and pyulog, aligned by
hand with numpy.interp and a last-value search."""

import warnings

import casadi as ca
import numpy as np
import pytest
import scipy.io

import casest

AP2 = casest.bundled_data_dir("ampyx_ap2", "validationDataFC114_1_v2_pc.mat")
ULOG = casest.bundled_data_dir("px4_ulog", "sample_log_small.ulg")
P = casest.Parameter


def _by_hand():
    v = scipy.io.loadmat(AP2)["validationData"]
    return v["controls"][0, 0], v["response"][0, 0]


def _roll_model():
    """p' = Lp p + Lda da, output p, the state started from the data (a rate-response model)."""
    p, da, Lp, Lda = (ca.SX.sym(n) for n in ("p", "da", "Lp", "Lda"))
    return casest.DynamicModel([P("Lp", -20.0, 0.0, -2.0), P("Lda", -50.0, 50.0, 1.0)],
                               [casest.State("p", "data")], ["da"], rhs={"p": Lp * p + Lda * da},
                               outputs={"p_m": p}, name="roll")


def test_from_mat_reads_struct_paths_as_loadmat_does():
    controls, response = _by_hand()
    paths = {"t": "validationData.controls.times", "da": "validationData.controls.aileron",
             "p_m": "validationData.response.w[0]", "p": "validationData.response.w[0]",
             "r_ned_12": "validationData.response.R[1, 2]", "q": "validationData.response.w[1]"}
    data = casest.Dataset.from_mat(_roll_model(), AP2, variables=paths, extra=["r_ned_12", "q"])
    np.testing.assert_array_equal(data.column("t"), controls["times"][0, 0].ravel())
    np.testing.assert_array_equal(data.column("da"), controls["aileron"][0, 0].ravel())
    np.testing.assert_array_equal(data.column("p_m"), response["w"][0, 0][0])
    np.testing.assert_array_equal(data.extra["p"], response["w"][0, 0][0])  # the state started from the data
    np.testing.assert_array_equal(data.extra["q"], response["w"][0, 0][1])
    np.testing.assert_array_equal(data.extra["r_ned_12"], response["R"][0, 0][1, 2, :])
    assert data.n_samples == 2467


def test_from_mat_time_from_sample_time_and_its_refusals():
    paths = {"da": "validationData.controls.aileron", "p_m": "validationData.response.w[0]",
             "p": "validationData.response.w[0]"}
    data = casest.Dataset.from_mat(_roll_model(), AP2, variables=paths, sample_time=0.02)
    np.testing.assert_allclose(data.column("t"), np.arange(2467) * 0.02, rtol=0, atol=1e-12)
    with pytest.raises(casest.DataError, match="mapped in variables= and built from sample_time="):
        casest.Dataset.from_mat(_roll_model(), AP2, variables={**paths, "t": "validationData.controls.times"},
                                sample_time=0.02)
    with pytest.raises(casest.DataError, match="positive number of seconds"):
        casest.Dataset.from_mat(_roll_model(), AP2, variables=paths, sample_time=0.0)


@pytest.mark.parametrize("where, message", [
    ("validationData.respons.w[0]", "no field 'respons' in 'validationData' for column 'p_m' (did you mean 'response'"),
    ("validationData.response.w[3]", "samples along axis 1, channels 3 (indices from 0)"),
    ("validationData.response.R[1]", "channels 3 x 3"),
    ("validationData.response.w", "not a vector; pick a column"),
    ("validationData.response.w.x", "'validationData.response.w' is not a struct"),
    ("validationData..w", "is not a path"),
])
def test_from_mat_names_a_wrong_struct_path(where, message):
    paths = {"t": "validationData.controls.times", "da": "validationData.controls.aileron", "p_m": where,
             "p": "validationData.response.w[0]"}
    with pytest.raises(casest.DataError) as info:
        casest.Dataset.from_mat(_roll_model(), AP2, variables=paths)
    assert message in str(info.value)


def test_from_mat_a_folder_is_named_a_folder(tmp_path):
    with pytest.raises(casest.DataError, match="is a folder, not a MAT file"):
        casest.Dataset.from_mat(_roll_model(), tmp_path)


def test_unit_conversions_give_one_summary_warning():
    pytest.importorskip("pint")
    alpha, beta, k = (ca.SX.sym(n) for n in ("alpha", "beta", "k"))
    model = casest.Model([P("k", -5.0, 5.0)], [casest.Signal("alpha", unit="deg"), casest.Signal("beta", unit="deg")],
                         {"z": k * alpha + beta})
    paths = {"alpha": "validationData.response.angleOfAttack", "beta": "validationData.response.sideSlip",
             "z": "validationData.response.airspeed"}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        data = casest.Dataset.from_mat(model, AP2, variables=paths, units={"alpha": "rad", "beta": "rad"})
    converted = [w for w in caught if "converted" in str(w.message)]
    assert len(converted) == 1, [str(w.message) for w in caught]
    assert "2 column(s) converted" in str(converted[0].message)
    _, response = _by_hand()
    np.testing.assert_allclose(data.column("alpha"), np.degrees(response["angleOfAttack"][0, 0].ravel()), rtol=1e-12)


def _log_by_hand(topic, field, multi_id=0):
    from pyulog import ULog

    entry = next(d for d in ULog(ULOG).data_list if d.name == topic and d.multi_id == multi_id)
    return entry.data["timestamp"].astype(float), entry.data[field].astype(float)


def _rate_model():
    q, k = ca.SX.sym("q"), ca.SX.sym("k")
    return casest.Model([P("k", -10.0, 10.0)], [casest.Signal("q")], {"p": k * q})


def test_from_ulog_aligns_topics_logged_at_different_rates():
    pytest.importorskip("pyulog")
    fields = {"q": "vehicle_angular_velocity.xyz[1]", "p": "sensor_combined.gyro_rad[0]",
              "armed": "actuator_armed.armed", "baro": "vehicle_air_data.baro_alt_meter"}
    data = casest.Dataset.from_ulog(_rate_model(), ULOG, fields, extra=["armed", "baro"], hold=["armed"])
    t_q, q = _log_by_hand("vehicle_angular_velocity", "xyz[1]")
    t_p, p = _log_by_hand("sensor_combined", "gyro_rad[0]")
    t_a, armed = _log_by_hand("actuator_armed", "armed")
    t_b, baro = _log_by_hand("vehicle_air_data", "baro_alt_meter")
    start, stop = max(t_q[0], t_p[0], t_a[0], t_b[0]), min(t_q[-1], t_p[-1], t_a[-1], t_b[-1])
    grid = t_q[(t_q >= start) & (t_q <= stop)]  # the fastest chosen topic's time stamps, by default
    np.testing.assert_array_equal(data.column("q"), q[(t_q >= start) & (t_q <= stop)])
    np.testing.assert_allclose(data.column("p"), np.interp(grid, t_p, p), rtol=0, atol=1e-15)
    np.testing.assert_allclose(data.extra["baro"], np.interp(grid, t_b, baro), rtol=0, atol=1e-12)
    held = armed[np.searchsorted(t_a, grid, side="right") - 1]
    np.testing.assert_array_equal(data.extra["armed"], held)
    np.testing.assert_allclose(data.extra["time"], (grid - grid[0]) * 1e-6)
    assert data.alignment["armed"].method == "held" and data.alignment["p"].method == "interpolated"
    assert 100 < data.alignment["baro"].source_rate * 10 < 1000 and data.alignment["q"].source_rate > 200


def test_from_ulog_uniform_grid_multi_id_and_a_dynamic_time_column():
    pytest.importorskip("pyulog")
    fields = {"q": "sensor_gyro[1].y", "p": "sensor_gyro[2].x"}
    data = casest.Dataset.from_ulog(_rate_model(), ULOG, fields, sample_time=0.05)
    t_1, y_1 = _log_by_hand("sensor_gyro", "y", multi_id=1)
    t_2, _ = _log_by_hand("sensor_gyro", "x", multi_id=2)
    start = max(t_1[0], t_2[0])
    grid = start + np.arange(data.n_samples) * 0.05e6
    assert grid[-1] <= min(t_1[-1], t_2[-1]) < grid[-1] + 0.05e6
    np.testing.assert_allclose(data.column("q"), np.interp(grid, t_1, y_1), rtol=0, atol=1e-12)
    assert data.alignment["q"].source == "sensor_gyro[1].y"


@pytest.mark.parametrize("fields, message", [
    ({"q": "vehicle_angular_velocity.xyz[5]", "p": "sensor_combined.gyro_rad[0]"},
     "topic 'vehicle_angular_velocity' has no field 'xyz[5]' (column 'q')"),
    ({"q": "vehicle_angular_vel.xyz[1]", "p": "sensor_combined.gyro_rad[0]"},
     "no topic 'vehicle_angular_vel' (column 'q') (did you mean 'vehicle_angular_velocity'"),
    ({"q": "sensor_accel[4].x", "p": "sensor_combined.gyro_rad[0]"}, "has no instance 4 (column 'q'); it has multi_id [0, 1, 2]"),
    ({"q": "sensor_accel.x"}, "fields= gives no log field for columns ['p']"),
    ({"q": "sensor_accel.x", "p": "sensor_accel.y", "r": "sensor_accel.z"}, "fields= names ['r']"),
    ({"q": "sensor_accel", "p": "sensor_accel.y"}, "is not a log field"),
])
def test_from_ulog_refuses_what_the_log_does_not_hold(fields, message):
    pytest.importorskip("pyulog")
    with pytest.raises(casest.DataError) as info:
        casest.Dataset.from_ulog(_rate_model(), ULOG, fields)
    assert message in str(info.value)


def test_from_ulog_alignment_is_stated_in_the_estimate():
    pytest.importorskip("pyulog")
    fields = {"q": "vehicle_angular_velocity.xyz[0]", "p": "sensor_combined.gyro_rad[0]"}
    data = casest.Dataset.from_ulog(_rate_model(), ULOG, fields)
    est = casest.estimate(_rate_model(), data)
    assert casest.status.NoteCode.ALIGNMENT in est.note_codes
    assert "sensor_combined[0].gyro_rad[0] interpolated" in est.report()


def test_a_damaged_ulog_is_said_to_be_damaged(tmp_path):
    """Truth: the bundled log with a tenth of its bytes zeroed in the middle (pyulog flags the
    corruption it skips): reading it warns, naming the file."""
    pytest.importorskip("pyulog")
    raw = bytearray(open(ULOG, "rb").read())
    raw[len(raw) // 2:len(raw) // 2 + len(raw) // 10] = bytes(len(raw) // 10)
    damaged = tmp_path / "damaged.ulg"
    damaged.write_bytes(bytes(raw))
    fields = {"q": "vehicle_angular_velocity.xyz[1]", "p": "sensor_combined.gyro_rad[0]"}
    with pytest.warns(RuntimeWarning, match="the ULog file is damaged"):
        casest.Dataset.from_ulog(_rate_model(), str(damaged), fields, sample_time=0.05)


def test_a_ulog_cut_short_is_said_to_be_cut_short(tmp_path):
    """Truth: the bundled log cut at 12 byte positions drawn with seed 20261202, and at the end of its
    last whole message before each: reading warns exactly when the cut falls inside a message
    (the message boundaries walked from the format's own headers: uint16 size, uint8 type after a
    16-byte file header); the whole log reads without a word."""
    pytest.importorskip("pyulog")
    from casest.data.ulog import bytes_missing_at_the_end

    raw = open(ULOG, "rb").read()
    boundaries, position = [], 16
    while position < len(raw):
        boundaries.append(position)
        position += 3 + int.from_bytes(raw[position:position + 2], "little")
    assert position == len(raw) and bytes_missing_at_the_end(ULOG) == 0
    fields = {"q": "vehicle_angular_velocity.xyz[1]", "p": "sensor_combined.gyro_rad[0]"}
    rng = np.random.default_rng(20261202)
    for cut in rng.integers(len(raw) // 2, len(raw) - 1, 12):
        whole = max(b for b in boundaries if b <= cut)
        for end, inside in ((int(cut), int(cut) not in boundaries), (whole, False)):
            path = tmp_path / f"cut_{end}.ulg"
            path.write_bytes(raw[:end])
            assert (bytes_missing_at_the_end(str(path)) > 0) == inside
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                casest.Dataset.from_ulog(_rate_model(), str(path), fields, sample_time=0.05)
            said = [w for w in caught if "ends inside a message" in str(w.message)]
            assert bool(said) == inside, (end, [str(w.message) for w in caught])
