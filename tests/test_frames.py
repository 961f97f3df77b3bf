"""pandas data frames in and out (the `frames` extra): a record read from a frame equals the same
CSV read by casest, units in the labels or a mapping are converted, a dynamic model's time may
be the index, and an estimate's tables come out as frames with its own numbers."""

import numpy as np
import pytest

import casest

pandas = pytest.importorskip("pandas")


def test_a_csv_through_pandas_equals_the_csv(scalar2, tmp_path):
    data = scalar2.simulate(0)
    model = scalar2.model()
    path = tmp_path / "record.csv"
    data.to_csv(path, units={"eta": "", "z": ""})
    direct = casest.Dataset.from_csv(model, path)
    framed = casest.Dataset.from_dataframe(model, pandas.read_csv(path))
    np.testing.assert_array_equal(framed.signals, direct.signals)
    np.testing.assert_array_equal(framed.outputs, direct.outputs)


def test_units_in_labels_or_a_mapping_are_converted():
    pint = pytest.importorskip("pint")  # noqa: F841
    m = casest.load_model_file("pitot5hole")
    model, data = m.model(), m.simulate(0).subset(slice(0, 50))
    columns = {name: data.column(name) for name in list(model.signal_names) + list(model.output_names)}
    frame = pandas.DataFrame(columns)
    unit = dict(zip(model.output_names, model.output_units))
    name = model.output_names[0]
    assert unit[name] == "m/s"
    frame[name] = frame[name] * 3.6  # the same speed in km/h
    with pytest.warns(UserWarning, match="converted"):
        from_mapping = casest.Dataset.from_dataframe(model, frame, units={name: "km/h"})
    np.testing.assert_allclose(from_mapping.column(name), data.column(name), rtol=1e-12)
    labelled = frame.rename(columns={name: f"{name} [km/h]"})
    with pytest.warns(UserWarning, match="converted"):
        from_label = casest.Dataset.from_dataframe(model, labelled)
    np.testing.assert_array_equal(from_label.column(name), from_mapping.column(name))


def test_a_dynamic_models_time_from_a_timedelta_index():
    sp = casest.load_model_file("short_period")
    model, data = sp.model(), sp.simulate(0).subset(slice(0, 200))
    t = data.column(model.time)
    frame = pandas.DataFrame({name: data.column(name) for name in model.signal_names[1:] + model.output_names},
                             index=pandas.to_timedelta(t - t[0] + 5.0, unit="s"))
    framed = casest.Dataset.from_dataframe(model, frame)
    np.testing.assert_allclose(framed.column(model.time), t - t[0], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(framed.outputs, data.outputs)
    with pytest.raises(casest.DataError, match="not increasing"):
        casest.Dataset.from_dataframe(model, frame.iloc[::-1])


def test_bad_frames_are_named():
    m = casest.load_model_file("scalar2")
    model = m.model()
    with pytest.raises(casest.DataError, match="pandas.DataFrame"):
        casest.Dataset.from_dataframe(model, {"eta": [1.0], "z": [2.0]})
    with pytest.raises(casest.DataError, match="not numeric"):
        casest.Dataset.from_dataframe(model, pandas.DataFrame({"eta": ["a", "b"], "z": [1.0, 2.0]}))


def test_an_estimates_tables_as_frames(scalar2):
    model, data = scalar2.model(), scalar2.simulate(0)
    est = casest.estimate(model, data)
    frame = est.to_dataframe()
    assert list(frame.index) == list(est.parameter_names) and frame.index.name == "parameter"
    np.testing.assert_array_equal(frame["value"].to_numpy(), est.theta)
    np.testing.assert_array_equal(frame["std"].to_numpy(), est.std)
    np.testing.assert_array_equal(frame["lower"].to_numpy(), est.lower_bounds)
    assert list(frame.columns) == ["value", "std", "unit", "lower", "upper", "at_bound", "std_note"]
    noise = est.noise_frame()
    np.testing.assert_array_equal(noise["variance"].to_numpy(), est.R)
    np.testing.assert_allclose(noise["std"].to_numpy(), np.sqrt(est.R), rtol=1e-15)


def test_a_pint_pandas_column_brings_its_unit():
    """A column of dtype pint[km/h] (pint-pandas) is converted to the model's m/s, not read as
    its bare numbers."""
    pytest.importorskip("pint_pandas")
    m = casest.load_model_file("pitot5hole")
    model, data = m.model(), m.simulate(0).subset(slice(0, 50))
    columns = {name: data.column(name) for name in list(model.signal_names) + list(model.output_names)}
    frame = pandas.DataFrame(columns)
    name = model.output_names[0]
    frame[name] = pandas.Series(frame[name] * 3.6, dtype="pint[km/h]")
    with pytest.warns(UserWarning, match="converted"):
        loaded = casest.Dataset.from_dataframe(model, frame)
    np.testing.assert_allclose(loaded.column(name), data.column(name), rtol=1e-12)
