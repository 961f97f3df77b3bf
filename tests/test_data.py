"""Datasets: shapes, names and finiteness are checked with messages that name the column."""

import numpy as np
import pytest

from casest import DataError, Dataset


def test_nan_is_reported_with_rows(scalar1):
    d = scalar1.simulate(0)
    z = d.column("z").copy()
    z[[3, 7]] = np.nan
    with pytest.raises(DataError, match=r"column 'z' has 2 NaN or infinite value\(s\) at row\(s\) 3, 7"):
        Dataset(scalar1.model(), {"eta": d.column("eta"), "z": z})


def test_missing_and_unknown_columns(scalar1):
    m = scalar1.model()
    eta = np.linspace(1, 10, 20)
    with pytest.raises(DataError, match=r"missing column\(s\) for model 'scalar1': 'z'"):
        Dataset(m, {"eta": eta})
    with pytest.raises(DataError, match=r"unknown column\(s\) 'etta' \(did you mean 'eta'\?\)"):
        Dataset(m, {"etta": eta, "z": eta})


def test_shapes(scalar1):
    m = scalar1.model()
    with pytest.raises(DataError, match="has 19 samples but 'eta' has 20"):
        Dataset(m, {"eta": np.ones(20), "z": np.ones(19)})
    with pytest.raises(DataError, match=r"outputs must have shape \(N, 1\)"):
        Dataset.from_arrays(m, np.ones((20, 1)), np.ones((20, 2)))
    with pytest.raises(DataError, match="need at least 5"):
        Dataset(m, {"eta": np.ones(3), "z": np.ones(3)})


def test_csv_round_trip_is_exact_and_keeps_extra_columns(tmp_path, scalar1):
    m = scalar1.model()
    d = scalar1.simulate(4)
    path = tmp_path / "data.csv"
    d.to_csv(path, units={"eta": "rad"})
    header = path.read_text().splitlines()[0]
    assert header == "eta [rad],z"
    back = Dataset.from_csv(m, path)
    np.testing.assert_array_equal(back.signals, d.signals)
    np.testing.assert_array_equal(back.outputs, d.outputs)
    text = path.read_text().splitlines()
    extra = ["time [s]," + text[0]] + [f"{i * 0.1}," + line for i, line in enumerate(text[1:])]
    path.write_text("\n".join(extra) + "\n")
    back = Dataset.from_csv(m, path)
    assert "time" in back.extra and back.n_samples == d.n_samples


def test_csv_empty_cell_is_a_named_nan(tmp_path, scalar1):
    path = tmp_path / "d.csv"
    path.write_text("eta,z\n" + "\n".join(f"{i},{i}" for i in range(10)) + "\n10,\n")
    with pytest.raises(DataError, match=r"column 'z' has 1 NaN .* row\(s\) 10"):
        Dataset.from_csv(scalar1.model(), path)


def test_subset_keeps_columns(scalar1):
    d = scalar1.simulate(0)
    s = d.subset(slice(10, 60))
    assert s.n_samples == 50
    np.testing.assert_array_equal(s.outputs, d.outputs[10:60])
