"""One result protocol for every estimator (casest.estimation.result_protocol.EstimateLike).

Truths: the protocol's declaration (each result is an instance of the runtime-checkable
protocol and answers each of its members), the JSON round trip (the reloaded result's values,
std and status equal the result's, exactly), and the parameter frame (its rows equal the
result's values and std).
"""

import casadi as ca
import numpy as np
import pytest

import casest
from casest.estimation.result_protocol import EstimateLike
from casest.status import TrustCode


def _regression_record():
    rng = np.random.default_rng(4)
    x = rng.uniform(-1.0, 1.0, 200)
    v = rng.uniform(-1.0, 1.0, 200)
    z = 0.5 + 2.0 * x - 1.0 * v + 0.3 * x * v + 0.05 * rng.standard_normal(200)
    xs, vs = ca.SX.sym("x"), ca.SX.sym("v")
    return {"x": x, "v": v, "z": z}, {"bias": 1, "x": xs, "v": vs, "xv": xs * vs}


def _estimates():
    scalar1 = casest.load_model_file("scalar1")
    sp = casest.load_model_file("short_period")
    tl = casest.load_model_file("turbulent_longitudinal")
    columns, terms = _regression_record()
    yield "two-stage", casest.estimate(scalar1.model(), scalar1.simulate(seed=0))
    yield "output error", casest.estimate(sp.model(), sp.simulate(0), start=sp.TRUTH)
    yield "filter error", casest.filter_error_estimate(tl.model(), tl.simulate(1, n_samples=300), tl.TURBULENCE_START,
                                                       start=tl.TRUTH, formulation="innovation")
    yield "frequency domain", casest.frequency_domain_estimate(sp.model(), sp.simulate(0),
                                                               2 * np.pi * np.arange(1, 41) / sp.DURATION)
    yield "regression", casest.regress("z", terms, columns)
    yield "total least squares", casest.total_least_squares("z", {"bias": 1, "x": terms["x"]}, columns,
                                                            noise_std={"x": 0.01})
    yield "stepwise", casest.stepwise("z", terms, columns, always=["bias"])


@pytest.fixture(scope="module")
def estimates():
    return dict(_estimates())


@pytest.mark.parametrize("kind", ["two-stage", "output error", "filter error", "frequency domain", "regression",
                                  "total least squares", "stepwise"])
def test_every_estimator_implements_the_protocol(estimates, kind, tmp_path):
    result = estimates[kind]
    assert isinstance(result, EstimateLike), kind
    n = len(result.parameter_names)
    assert np.shape(result.theta) == (n,) and np.shape(result.std) == (n,)
    assert np.shape(result.covariance)[0] >= n and isinstance(result.success, (bool, np.bool_))
    assert isinstance(result.status, str) and all(isinstance(note.code, casest.status.NoteCode)
                                                  for note in result.notes)
    assert set(result.values) == set(result.parameter_names) and set(result.stds) == set(result.parameter_names)
    code, reason = result.conclusion()
    assert isinstance(code, TrustCode) and reason and result.trust()[1] == reason
    assert "[[Conclusion]]" in result.report()
    path = tmp_path / "result.json"
    result.to_json(str(path))
    back = type(result).from_json(str(path))
    np.testing.assert_array_equal(back.theta, result.theta)
    np.testing.assert_array_equal(back.std, result.std)
    assert back.status == result.status and list(back.parameter_names) == list(result.parameter_names)
    frame = result.to_dataframe()
    np.testing.assert_array_equal(frame["value"].to_numpy(), np.asarray(result.theta, dtype=float))
    assert list(frame.index) == list(result.parameter_names)


def test_a_frequency_estimate_says_caution_where_its_std_are_too_small(estimates):
    """Frequencies closer than the record's resolution: the coded note makes the trust line CAUTION."""
    sp = casest.load_model_file("short_period")
    fine = casest.frequency_domain_estimate(sp.model(), sp.simulate(0), np.linspace(0.5, 6.0, 80))
    assert fine.conclusion()[0] is TrustCode.CAUTION and "resolution" in fine.conclusion()[1]


@pytest.mark.parametrize("kind", ["two-stage", "output error", "filter error", "frequency domain", "regression",
                                  "total least squares", "stepwise"])
def test_every_estimate_writes_one_self_contained_page(estimates, kind, tmp_path):
    """Truth: the result's own values: the page's parameter table holds them to its printed digits,
    the conclusion is the result's, nothing is fetched from outside (no http, no other file)."""
    import re

    result = estimates[kind]
    path = tmp_path / "report.html"
    page = result.to_html(str(path))
    assert path.read_text() == page and page.startswith("<!DOCTYPE html>")
    assert "http" not in page and "src='data:image/png;base64," in page  # the correlations, embedded
    values = [float(v) for v in re.findall(r"<td class='value'>([^<]+)</td>", page)]
    np.testing.assert_allclose(values, np.asarray(result.theta, dtype=float), rtol=1e-9)
    assert result.conclusion()[0].value.upper() in page
    assert "<table" in result._repr_html_()


@pytest.mark.parametrize("kind", ["two-stage", "output error", "filter error", "frequency domain", "regression",
                                  "total least squares", "stepwise"])
def test_a_missing_std_reads_the_same_in_every_report(estimates, kind):
    """Truth: the first parameter's std set to NaN (what a held, fixed or unidentifiable parameter
    has); every text report and HTML page shows it as ``n/a`` (reporting.NO_STD), never as "nan"."""
    import dataclasses

    from casest.estimation.reporting import NO_STD

    result = estimates[kind]
    std = np.array(result.std, dtype=float)
    std[0] = np.nan
    changes = {"std": std}
    if kind == "filter error":  # its noise stds too
        changes["process_noise_std"] = {k: np.nan for k in result.process_noise_std}
        if result.innovation_covariance_std is not None:
            changes["innovation_covariance_std"] = np.full_like(result.innovation_covariance_std, np.nan)
    if kind == "stepwise":  # its std are its final fit's
        missing = dataclasses.replace(result, fit=dataclasses.replace(result.fit, **changes))
    elif dataclasses.is_dataclass(result):
        missing = dataclasses.replace(result, **changes)
    else:
        missing = type(result)(**{**result.__dict__, **changes})
    texts = [missing.report(), missing._repr_html_()]
    if hasattr(missing, "table"):
        texts.append(missing.table())
    for text in texts:
        assert NO_STD in text
        assert "nan" not in text.replace("Nan", "").lower().replace("nanosecond", ""), text


_TAGS = [{"array"}, {"array", "kind"}, {"float"}, {"list"}, {"tuple"}, {"mapping"}, {"note"}, {"code", "type"},
         {"record", "type"}]


def _in_schema(value) -> bool:
    """Whether a saved field is JSON's own value or one of result_schema's tags (its items alike)."""
    if value is None or isinstance(value, (str, bool, int)):
        return True
    if isinstance(value, float):
        return np.isfinite(value)
    if not isinstance(value, dict) or set(value) not in _TAGS:
        return False
    inner = value.get("list", value.get("tuple"))
    if inner is not None:
        return all(_in_schema(v) for v in inner)
    return all(_in_schema(v) for v in value["mapping"].values()) if "mapping" in value else True


@pytest.mark.parametrize("kind", ["two-stage", "output error", "filter error", "frequency domain", "regression",
                                  "total least squares", "stepwise"])
def test_every_result_writes_the_one_schema(estimates, kind):
    """Truth: casest.estimation.result_schema. Every result type's file names its kind and the schema's
    version, and each field is a plain JSON value or one of the schema's tags."""
    import json

    from casest.estimation.result_schema import SCHEMA_VERSION

    result = estimates[kind]
    saved = json.loads(result.to_json())
    assert saved["format"] == f"casest.{type(result).__name__}/{SCHEMA_VERSION}"
    loose = [k for k, v in saved.items() if k not in ("format", "content_sha256") and not _in_schema(v)]
    assert not loose, loose
