"""The merged limit of two exchangeable terms (casest.two_stage.merged_limit): the limit model is
the term plus its derivative term, and an estimate whose cost falls towards it says so and
carries the limit's fit."""

import json
import warnings

import casadi as ca
import numpy as np
import pytest

import casest
from casest.status import NoteCode, TrustCode
from casest.two_stage.merged_limit import MergedLimit, limit_model, merging_exchanges, with_merged_limit
from casest.two_stage.symmetry import model_symmetries

X = np.linspace(0.0, 10.0, 80)
#: the truth of the simulated record: y = c + (a + d x) exp(-b x), the limit of two merging
#: exponentials (d x exp(-b x) = -d * d/db exp(-b x))
TRUTH = {"c": 0.3, "a": 1.5, "d": 2.0, "b": 0.8}
NOISE = 0.01


def _two_exponentials() -> casest.Model:
    xs = ca.SX.sym("x")
    c, a0, a1, b0, b1 = (ca.SX.sym(n) for n in ("c", "a0", "a1", "b0", "b1"))
    params = [casest.Parameter("c", nominal=0.0), casest.Parameter("a0", nominal=0.0),
              casest.Parameter("b0", 0.01, 10.0, prior=casest.LogUniform()), casest.Parameter("a1", nominal=0.0),
              casest.Parameter("b1", 0.01, 10.0, prior=casest.LogUniform())]
    return casest.Model(params, ["x"], {"y": c + a0 * ca.exp(-b0 * xs) + a1 * ca.exp(-b1 * xs)})


def _limit_record(seed: int = 3) -> casest.Dataset:
    rng = np.random.default_rng(seed)
    y = TRUTH["c"] + (TRUTH["a"] + TRUTH["d"] * X) * np.exp(-TRUTH["b"] * X) + NOISE * rng.standard_normal(X.size)
    return casest.Dataset(_two_exponentials(), {"x": X, "y": y})


@pytest.fixture(scope="module")
def limit_estimate():
    """The two-exponential model's estimate on the record simulated from the limit (seed 3)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return casest.estimate(_two_exponentials(), _limit_record())


def test_the_limit_model_is_the_term_plus_its_derivative_term():
    """Analytic truth: merging b1 into b0 turns a0 exp(-b0 x) + a1 exp(-b1 x) into
    a0 exp(-b0 x) + a0_db0 * (-x exp(-b0 x)); the derivative amplitude is unbounded and named."""
    model = _two_exponentials()
    names = model.parameter_names
    limit = limit_model(model, [(names.index("b0"), names.index("b1"))], (names.index("a0"), names.index("a1")))
    assert limit.parameter_names == ("c", "a0", "a0_db0", "b0")
    assert np.isinf(limit.lower_bounds[2]) and np.isinf(limit.upper_bounds[2])
    theta = np.array([0.2, 1.3, -0.7, 0.45])
    z = np.array(limit.function(X.reshape(1, -1), theta)).ravel()
    expected = 0.2 + 1.3 * np.exp(-0.45 * X) - 0.7 * (-X * np.exp(-0.45 * X))
    assert np.allclose(z, expected, rtol=1e-13, atol=1e-13)


def test_a_bounded_amplitude_is_no_merging_exchange():
    """With a box on the amplitudes the terms cannot cancel without bound: the minimum is attained
    (on the box), and no limit is probed."""
    model = _two_exponentials()
    theta = np.array([0.3, 1.0, 0.5, -1.0, 2.0])
    unbounded = merging_exchanges(model, model_symmetries(model, X[:, None], theta), [0, 1, 3])
    assert unbounded == [([(2, 4)], [(1, 3)])]
    bounded = model.with_bounds({"a0": (-1e3, 1e3), "a1": (-1e3, 1e3)})
    assert merging_exchanges(bounded, model_symmetries(bounded, X[:, None], theta), [0, 1, 3]) == []


def test_data_from_the_limit_end_in_a_caution_that_carries_the_limit_fit(limit_estimate):
    """Truth: the record is simulated from the limit itself (TRUTH, noise std 0.01, seed 3), which no
    point of the two-exponential model attains. The estimate is a CAUTION naming the merging terms, its
    merged limit fits better than the estimate, and the limit's parameters lie within 3 std of the truth
    (d with the derivative's sign: d x exp(-b x) = -d * d/db exp(-b x))."""
    model, est = _two_exponentials(), limit_estimate
    assert est.conclusion()[0] is TrustCode.CAUTION
    assert NoteCode.MERGING in est.note_codes
    limit = est.merged_limit
    assert isinstance(limit, MergedLimit) and limit.cost < est.cost and limit.estimate_cost == est.cost
    assert limit.merged == (("b0", "b1"),) and limit.amplitudes == ("a0", "a1")
    truth = np.array([TRUTH["c"], TRUTH["a"], -TRUTH["d"], TRUTH["b"]])
    assert np.all(np.isfinite(limit.std)) and np.all(np.abs(limit.theta - truth) <= 3 * limit.std), (limit.theta, limit.std)
    # the record names the limit model it was fitted with; its cost there is the record's
    rebuilt = limit.limit_model(model)
    assert rebuilt.parameter_names == limit.parameter_names


def test_the_merged_limit_is_saved_and_reloaded(tmp_path, limit_estimate):
    """A result file keeps the limit; a file written before the field existed reads back without one."""
    est = limit_estimate
    path = tmp_path / "estimate.json"
    est.to_json(path)
    back = casest.Estimate.from_json(path).merged_limit
    assert back.merged == est.merged_limit.merged and back.parameter_names == est.merged_limit.parameter_names
    assert np.array_equal(back.theta, est.merged_limit.theta) and np.array_equal(back.std, est.merged_limit.std)
    assert back.cost == est.merged_limit.cost
    older = json.loads(est.to_json())
    older.pop("merged_limit")
    older.pop("content_sha256")  # files of that time had no digest either
    assert casest.Estimate.from_json(json.dumps(older)).merged_limit is None


def test_a_limit_that_is_not_lower_leaves_the_estimate_alone(limit_estimate):
    """with_merged_limit adds nothing when the limit's cost is not below the estimate's."""
    est = limit_estimate
    higher = MergedLimit(est.merged_limit.merged, est.merged_limit.amplitudes, est.merged_limit.parameter_names,
                         est.merged_limit.theta, est.merged_limit.std, est.cost + 1.0, est.cost)
    plain = type(est)(**{**est.__dict__, "merged_limit": None})
    assert with_merged_limit(plain, higher) is plain
    assert with_merged_limit(plain, None) is plain


def test_mistaken_merged_limits_are_named(limit_estimate):
    """Indices out of range, repeated or empty, a dynamic model, terms that are not exchangeable
    (b0 with the constant c: swapping them changes the outputs), a record that is not a
    MergedLimit, a damaged record and one naming parameters the model lacks: each a named error."""
    model = _two_exponentials()
    with pytest.raises(casest.OptionError, match="distinct indices below 5"):
        limit_model(model, [(9, 1)], (0, 1))
    with pytest.raises(casest.OptionError, match="at least one"):
        limit_model(model, [], (1, 3))
    with pytest.raises(casest.OptionError, match="not exchangeable"):
        limit_model(model, [(2, 0)], (1, 3))
    with pytest.raises(casest.OptionError, match="static casest.Model"):
        limit_model(casest.load_model_file("short_period").model(), [(0, 1)], (2, 3))
    with pytest.raises(casest.OptionError, match="takes a MergedLimit or None"):
        with_merged_limit(limit_estimate, "garbage")
    with pytest.raises(casest.ResultFileError, match="missing or damaged field"):
        MergedLimit.from_dict({})
    record = MergedLimit((("b0", "bx"),), ("a0",), ("c",), np.zeros(1), np.zeros(1), 0.0, 0.0)
    with pytest.raises(casest.OptionError, match="needs two amplitudes"):
        record.limit_model(model)
