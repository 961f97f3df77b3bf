"""MATLAB .mat records: Dataset.from_mat reads vectors and matrix columns, converts units as
a CSV header does, and names every problem. Truth: scalar2's simulated record (seed 0)
written with scipy.io.savemat and read back (to 1e-12 after a deg -> rad conversion)."""

import numpy as np
import pytest
import scipy.io

import casest

scalar2 = casest.load_model_file("scalar2")


@pytest.fixture()
def record(tmp_path):
    data = scalar2.simulate(0)
    path = tmp_path / "flight.mat"
    scipy.io.savemat(path, {"ETA_deg": np.degrees(data.column("eta")), "eta": data.column("eta"),
                            "Z": np.column_stack([2 * data.column("z"), data.column("z")]), "z": data.column("z")})
    return path, data


def test_vectors_of_the_same_names_are_read(record):
    path, data = record
    read = casest.Dataset.from_mat(scalar2.model(), path)
    np.testing.assert_array_equal(read.signals, data.signals)
    np.testing.assert_array_equal(read.outputs, data.outputs)
    assert read.undeclared_units == {}


def test_mapped_variables_matrix_columns_and_units(record):
    pytest.importorskip("pint")
    path, data = record
    with pytest.warns(UserWarning, match=r"'eta' converted from \[deg\] to \[rad\]"):
        read = casest.Dataset.from_mat(scalar2.model(), path, variables={"eta": "ETA_deg", "z": ("Z", 1)},
                                       units={"eta": "deg"})
    np.testing.assert_allclose(read.column("eta"), data.column("eta"), rtol=1e-12)
    np.testing.assert_array_equal(read.column("z"), data.column("z"))
    est = casest.estimate(scalar2.model(), read)
    assert est.conclusion()[0] is casest.status.TrustCode.TRUSTED


@pytest.mark.parametrize("kwargs, message", [
    ({"variables": {"eta": "ETA_dg"}}, "no variable 'ETA_dg' for column 'eta' (did you mean 'ETA_deg'"),
    ({"variables": {"z": ("Z", 2)}}, "column 2 of variable 'Z' (shape (100, 2)) does not exist"),
    ({"variables": {"z": "Z"}}, "has shape (100, 2), not a vector; pick a column with variables={'z': ('Z', k)}"),
    ({"variables": {"q": "z"}}, "variables= names ['q'], which are not signals or outputs of the model"),
    ({"units": {"alpha": "deg"}}, "units= names ['alpha'], which are not signals or outputs of the model"),
])
def test_a_wrong_mapping_is_named(record, kwargs, message):
    path, _ = record
    with pytest.raises(casest.DataError) as info:
        casest.Dataset.from_mat(scalar2.model(), path, **kwargs)
    assert message in str(info.value)


def test_a_file_that_is_not_a_mat_file_is_a_data_error(tmp_path):
    path = tmp_path / "notes.mat"
    path.write_text("hello")
    with pytest.raises(casest.DataError, match="not a readable MATLAB .mat file"):
        casest.Dataset.from_mat(scalar2.model(), path)
    with pytest.raises(casest.DataError, match="does not exist"):
        casest.Dataset.from_mat(scalar2.model(), tmp_path / "absent.mat")
    scipy.io.savemat(tmp_path / "text.mat", {"eta": "abc", "z": np.ones(5)})
    with pytest.raises(casest.DataError, match="'eta' .* is not a real numeric array"):
        casest.Dataset.from_mat(scalar2.model(), tmp_path / "text.mat")


def test_a_dynamic_record_with_its_time_column(tmp_path):
    """A DynamicModel's time is one of the columns read (truth: dx/dt = -k x, k = 2, simulated)."""
    import casadi as ca

    k, x = ca.SX.sym("k"), ca.SX.sym("x")
    model = casest.DynamicModel([casest.Parameter("k", 0.1, 5.0, 1.0)], [casest.State("x", 1.0)], [], {"x": -k * x},
                                {"y": x}, name="decay")
    t = np.linspace(0, 2, 41)
    _, clean = model.simulate({"k": 2.0}, model.dataset({"t": t, "y": np.zeros_like(t)}))
    y = clean[:, 0] + np.random.default_rng(0).normal(0, 0.01, t.size)
    scipy.io.savemat(tmp_path / "decay.mat", {"time": t.reshape(-1, 1), "y": y})
    data = casest.Dataset.from_mat(model, tmp_path / "decay.mat", variables={"t": "time"})
    est = casest.estimate(model, data)
    assert est.success and abs(est.values["k"] - 2.0) < 3 * est.stds["k"]


def test_the_command_line_reads_a_mat_file(record, capsys):
    from casest.apps.cli import main as cli

    path, _ = record
    assert cli(["solve", "scalar2", "--data", str(path)]) == 0
    assert "[[Conclusion]] trust it" in capsys.readouterr().out
