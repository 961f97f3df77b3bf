"""Fuzz the newer entry points (filters and smoothers, the discretisation, recursive ML, the joint
filter, delays, result files, MAT paths, campaign folders, signal smoothing, lookup tables) with Hypothesis (derandomized, bounded): every call ends
in a finite result or a casest error (a ``CasestError``) that names the problem; never another
exception, never a NaN result. The longer campaign: ``python3 scripts/campaigns/fuzz_inputs.py --apis``.
"""

import json
import os

import casadi as ca
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import casest
from casest.errors import CasestError

EXAMPLES = int(os.environ.get("CASEST_FUZZ_EXAMPLES", "40"))
SETTINGS = dict(max_examples=EXAMPLES, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

# values that break numerics: NaN, infinities, huge and tiny magnitudes, negatives, zero
BAD = st.sampled_from([np.nan, np.inf, -np.inf, 1e200, -1e200, 1e-200, -1.0, 0.0, 1.0, 2.5])


@st.composite
def matrices(draw, shape):
    """A matrix of ``shape`` (sometimes of another shape), its entries sometimes replaced by bad values."""
    if draw(st.integers(0, 9)) == 0:
        shape = tuple(max(0, s + draw(st.integers(-1, 1))) for s in shape)
    base = np.eye(*shape) * 0.1 if len(shape) == 2 and shape[0] == shape[1] else np.full(shape, 0.3)
    base = np.array(base, dtype=float)
    for _ in range(draw(st.integers(0, 2))):
        if base.size:
            base.flat[draw(st.integers(0, base.size - 1))] = draw(BAD)
    return base


def _finite_or_casest_error(call):
    try:
        result = call()
    except CasestError:
        return None
    return result


@settings(**SETTINGS)
@given(Phi=matrices((2, 2)), C=matrices((1, 2)), Q=matrices((2, 2)), R=matrices((1, 1)), P0=matrices((2, 2)),
       y=matrices((20, 1)))
def test_kalman_filter_and_smoother(Phi, C, Q, R, P0, y):
    from casest.filters import KalmanFilter, rts_smoother

    def run():
        kf = KalmanFilter(Phi, C, Q, R, np.zeros(2), P0)
        result = kf.filter(y)
        smoothed = rts_smoother(result, process_noise=Q)
        return result, smoothed

    out = _finite_or_casest_error(run)
    if out is not None:
        result, smoothed = out
        assert np.all(np.isfinite(result.x_filtered)) and np.all(np.isfinite(smoothed.x))


@settings(**SETTINGS)
@given(A=matrices((2, 2)), B=matrices((2, 1)), G=matrices((2, 2)), Qc=matrices((2, 2)),
       dt=st.sampled_from([0.1, 0.0, -1.0, np.nan, np.inf]))
def test_continuous_to_discrete(A, B, G, Qc, dt):
    from casest.filters import continuous_to_discrete

    out = _finite_or_casest_error(lambda: continuous_to_discrete(A, B, G, Qc, dt))
    if out is not None:
        Phi, Psi, Qd = out
        assert np.all(np.isfinite(Phi)) and np.all(np.isfinite(Qd)) and np.linalg.eigvalsh(Qd).min() >= -1e-9


@pytest.fixture(scope="module")
def scalar2():
    module = casest.load_model_file("scalar2")
    return module.model(), module.simulate(0)


@settings(**SETTINGS)
@given(signals=matrices((5, 1)), outputs=matrices((5, 1)), R0=st.sampled_from([0.01, 0.0, -1.0, np.nan, 1e300]))
def test_recursive_ml(scalar2, signals, outputs, R0):
    from casest.recursive import RecursiveML

    model, _ = scalar2

    def run():
        rml = RecursiveML(model, model.nominal, [R0])
        rml.update(signals, outputs)
        return rml.theta

    theta = _finite_or_casest_error(run)
    if theta is not None:
        assert np.all(np.isfinite(theta))


def _pendulum():
    ang, rate, c, L = (ca.SX.sym(n) for n in ("ang", "rate", "c", "L"))
    return casest.DynamicModel([casest.Parameter("c", 0.0, 2.0, 0.3), casest.Parameter("L", 0.5, 2.0, 1.0)],
                               [casest.State("ang", 1.0), casest.State("rate", 0.0)], [],
                               rhs={"ang": rate, "rate": -9.81 / L * ca.sin(ang) - c * rate},
                               outputs={"px": L * ca.sin(ang)}, name="fuzz_pendulum")


@settings(**SETTINGS)
@given(theta=st.sampled_from([{"c": 0.1, "L": 1.0}, {"c": 0.1}, {"c": np.nan, "L": 1.0}, [0.1, 1.0], {"z": 1.0}]),
       estimate=st.sampled_from([{"c": 0.04}, {}, {"k": 1.0}, {"c": -1.0}, {"c": np.nan}]),
       noise=st.sampled_from([{"rate": 0.05}, {"rat": 0.05}, {"rate": -1.0}, {"rate": np.nan}]),
       R=matrices((1, 1)), P0=matrices((2, 2)))
def test_joint_filter(theta, estimate, noise, R, P0):
    from casest.recursive.joint import joint_filter

    _finite_or_casest_error(lambda: joint_filter(_pendulum(), theta, estimate, noise, R, P0))


@settings(**SETTINGS)
@given(key=st.sampled_from(["u", "y", "x", "w"]), tau=st.sampled_from(["tau", "k", 0.05, -0.1, np.nan, 1e9]),
       bound=st.sampled_from([0.2, 0.0, 1000.0, np.inf]), dt=st.sampled_from([0.02, 0.0, None, np.nan, -0.02]))
def test_delays(key, tau, bound, dt):
    x, u, k = (ca.SX.sym(n) for n in ("x", "u", "k"))

    def build():
        return casest.DynamicModel([casest.Parameter("k", 0.1, 5.0, 1.0), casest.Parameter("tau", 0.0, bound, 0.0)],
                                   [casest.State("x", 0.0)], ["u"], rhs={"x": k * u - x}, outputs={"y": x},
                                   delays={key: tau}, sample_time=dt)

    _finite_or_casest_error(build)


@pytest.fixture(scope="module")
def result_json(scalar2):
    model, data = scalar2
    return json.loads(casest.estimate(model, data).to_json())


@settings(**SETTINGS)
@given(field=st.sampled_from(["theta", "std", "R", "covariance", "lower_bounds", "parameter_names", "cost", "format",
                              "notes", "landscape", "starts"]),
       value=st.sampled_from([None, -1.0, "x", [], {}, [1.0], 1e400]))
def test_result_files(tmp_path, result_json, field, value):
    data = json.loads(json.dumps(result_json))
    saved = data[field]["array"] if isinstance(data.get(field), dict) and "array" in data[field] else None
    if saved is not None and "values" in saved and not isinstance(value, (dict, list, str)):
        saved["values"] = [value] * len(saved["values"])
    else:
        data[field] = value
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(data))
    loaded = _finite_or_casest_error(lambda: casest.Estimate.from_json(path))
    if loaded is not None:
        assert np.all(np.isfinite(loaded.theta)) and np.all(np.asarray(loaded.R) > 0)


@settings(**SETTINGS)
@given(path=st.sampled_from(["validationData.response.w[1]", "validationData.response.w[9]", "validationData.response",
                             "validationData..w", "validationData.response.R[0]", "nothing", "validationData.times",
                             "validationData.response.w[0, 0]", "[1]", "validationData.initialState.p[0]"]))
def test_mat_paths(path):
    q, k = ca.SX.sym("q"), ca.SX.sym("k")
    model = casest.Model([casest.Parameter("k", -10.0, 10.0)], [casest.Signal("q")], {"p": k * q})
    mat = casest.bundled_data_dir("ampyx_ap2", "validationDataFC114_1_v2_pc.mat")
    data = _finite_or_casest_error(lambda: casest.Dataset.from_mat(
        model, mat, variables={"q": path, "p": "validationData.response.w[0]"}))
    if data is not None:
        assert np.all(np.isfinite(data.signals))


@settings(**SETTINGS)
@given(files=st.lists(st.sampled_from(["summary.md", "runs.csv", "summary.json", "notes.txt", ".lock", "config.json"]),
                      max_size=4, unique=True),
       as_file=st.booleans())
def test_campaign_folders(tmp_path_factory, files, as_file):
    """A campaign writes only into a new or empty folder, or one of its own (with its config.json):
    every other folder is refused with a CampaignError, and no file in it changes."""
    from casest.checks import own_folder
    from casest.errors import CampaignError

    root = tmp_path_factory.mktemp("campaign")
    out = root / "out"
    if as_file:
        out.write_text("a user's file")
    else:
        out.mkdir()
        for name in files:
            (out / name).write_text(f"the user's {name}")
    before = {p.name: p.read_text() for p in out.iterdir()} if out.is_dir() else out.read_text()
    foreign = as_file or (bool(set(files) - {".lock"}) and "config.json" not in files)
    try:
        own_folder(out, "config.json", CampaignError, ignored=(".lock",))
        assert not foreign
    except CampaignError:
        assert foreign
    after = {p.name: p.read_text() for p in out.iterdir()} if out.is_dir() else out.read_text()
    assert after == before


@settings(**SETTINGS)
@given(y=matrices((40,)), dt=BAD, window=st.sampled_from([-3, 0, 2, 5, 7, 41, 101]),
       order=st.sampled_from([-1, 0, 2, 3, 6, 9]), derivative=st.sampled_from([-1, 0, 1, 2, 5]))
def test_signal_smoothing(y, dt, window, order, derivative):
    from casest.data import fourier_smooth, savitzky_golay

    smoothed = _finite_or_casest_error(lambda: savitzky_golay(y, dt, window, order, derivative))
    if smoothed is not None:
        assert smoothed.shape == y.shape and np.all(np.isfinite(smoothed))
    filtered = _finite_or_casest_error(lambda: fourier_smooth(y, dt))
    if filtered is not None:
        assert np.all(np.isfinite(filtered))


@settings(**SETTINGS)
@given(grid=matrices((5,)), values=matrices((5,)), method=st.sampled_from(["linear", "bspline", "cubic"]))
def test_lookup_tables(grid, values, method):
    table = _finite_or_casest_error(lambda: casest.lookup_table("T", [grid], values, method))
    if table is not None:
        assert np.all(np.diff(grid) > 0)
