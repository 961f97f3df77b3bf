"""Estimate: lossless JSON, fixed-section report, the solve script end to end."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import casest
from casest import Estimate

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _assert_same(a: Estimate, b: Estimate):
    for key, value in a.__dict__.items():
        other = getattr(b, key)
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(value, other)
        elif key in ("landscape", "residual_analysis", "diagnosis") and value is not None:  # records holding arrays
            for k, v in value.__dict__.items():
                if isinstance(v, np.ndarray):
                    np.testing.assert_array_equal(v, getattr(other, k))
                else:
                    assert v == getattr(other, k), k
        else:
            assert value == other, key


def test_json_round_trip_is_lossless(tmp_path, scalar2):
    model = scalar2.model()
    est = casest.estimate(model, scalar2.simulate(0))
    path = tmp_path / "est.json"
    est.to_json(path)
    back = Estimate.from_json(path)
    _assert_same(est, back)
    assert back.report() == est.report()
    def bare_token(token):
        raise AssertionError(f"bare {token} in the JSON")

    json.loads(path.read_text(), parse_constant=bare_token)  # strict JSON: no bare NaN or Infinity tokens


def test_large_arrays_are_stored_compactly_and_the_landscape_is_optional(tmp_path, scalar2):
    """The landscape's arrays as base64 of their bytes (bit-exact, checked by the round trip
    above); a file without the landscape loads with landscape None; damaged bytes are a
    ResultFileError."""
    est = casest.estimate(scalar2.model(), scalar2.simulate(0))
    full = json.loads(est.to_json(tmp_path / "full.json"))
    assert "base64" in full["landscape"]["record"]["trace_R"] and "values" in full["theta"]["array"]  # small arrays stay readable
    lean = est.to_json(tmp_path / "lean.json", landscape=False)
    assert len(lean) < 0.2 * len(json.dumps(full, indent=1))
    back = Estimate.from_json(tmp_path / "lean.json")
    assert back.landscape is None and back.report().split("\n")[0] == est.report().split("\n")[0]
    np.testing.assert_array_equal(back.theta, est.theta)
    full["covariance"] = {"array": {"shape": [40, 40], "dtype": "<f8", "base64": "not base64!"}}
    with pytest.raises(casest.ResultFileError, match="base64"):
        Estimate.from_json(json.dumps(full))


def test_round_trip_keeps_missing_std(tmp_path, scalar1):
    model = scalar1.model()
    est = casest.estimate(model, scalar1.simulate(0), start={"a": 0.0, "b": 0.0, "c": 0.0}, mode="full")
    est.std[1] = np.nan
    est.std_reasons[1] = "at lower bound: held fixed, std not available"
    back = Estimate.from_json(est.to_json())
    assert np.isnan(back.std[1]) and back.stds["b"] is None and back.landscape is None


def test_report_sections(scalar2):
    text = casest.estimate(scalar2.model(), scalar2.simulate(0)).report()
    order = ["[[Fit Statistics]]", "[[Parameters]]", "[[Noise]]", "[[Correlations]]", "[[Stage 1]]", "[[Conclusion]]"]
    positions = [text.index(s) for s in order]
    assert positions == sorted(positions)
    assert "C(b, c) = -0.8" in text  # b and c are strongly anti-correlated in Eq. 33
    assert "b = 0.04" in text and "+/-" in text and "[0, 0.5]" in text
    assert "one standard deviation" in text and "noise std" in text
    assert " rad " in text.split("[[Parameters]]")[1].split("[[Noise]]")[0]  # c is declared in rad
    assert "[[Conclusion]] trust it: converged" in text
    # the stage-1 section names no stage-2 mode of its own (it cannot contradict the one used)
    assert "stage 2" not in text.split("[[Stage 1]]")[1].split("[[")[0]


def test_report_conclusion_warns(scalar2):
    """A failed solve and missing error bars give a CAUTION line that says why."""
    est = casest.estimate(scalar2.model(), scalar2.simulate(0), solver_settings=casest.SolverSettings(max_iter=1))
    assert not est.success
    assert "[[Conclusion]] CAUTION: do not rely on it: stage 2 did not converge" in est.report()
    html = est._repr_html_()
    assert "<table>" in html and "CAUTION" in html and "std (1 sigma)" in html


def test_solve_script_writes_json_that_reloads(tmp_path):
    out = tmp_path / "e.json"
    proc = subprocess.run(
        [sys.executable, os.path.join(REPO, "scripts", "examples", "solve.py"), "scalar1", "--seed", "2", "--json", str(out)],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "[[Parameters]]" in proc.stdout and "[[Truth]]" in proc.stdout
    est = Estimate.from_json(out)
    assert est.success and set(est.values) == {"a", "b", "c"}


def test_solve_script_reads_csv(tmp_path, scalar2):
    csv = tmp_path / "d.csv"
    scalar2.simulate(3).to_csv(csv)
    proc = subprocess.run(
        [sys.executable, os.path.join(REPO, "scripts", "examples", "solve.py"), "scalar2", "--data", str(csv)],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "[[Truth]]" not in proc.stdout


def test_codes_beside_the_words(tmp_path):
    """Outcome, std reasons and notes carry codes that survive a JSON round trip."""
    from casest.status import NoteCode, Outcome, StdReason

    hard = casest.load_model_file(os.path.join(REPO, "models", "robustness.py"))
    model, data = hard.exp3()
    est = casest.estimate(model, data, fixed={"k1": 0.3})
    assert est.outcome is Outcome.CONVERGED
    assert est.std_reason_codes[model.parameter_names.index("k1")] is StdReason.FIXED
    assert NoteCode.STARTS in est.note_codes and NoteCode.FIXED in est.note_codes
    back = Estimate.from_json(est.to_json(tmp_path / "e.json") and tmp_path / "e.json")
    assert back.outcome is Outcome.CONVERGED and back.note_codes == est.note_codes
    assert back.std_reason_codes == est.std_reason_codes
    failed = casest.estimate(model, data, solver_settings=casest.SolverSettings(max_iter=1))
    assert failed.outcome in (Outcome.NOT_CONVERGED, Outcome.NO_IMPROVEMENT, Outcome.CLIMBED) and not failed.success
    assert NoteCode.NOT_VERIFIED in failed.note_codes


def test_a_plausible_edit_is_found_by_the_content_digest(tmp_path, scalar2):
    """A value changed to another one inside its bounds passes every field check; the digest casest
    wrote finds it. Without the digest field the file loads (older files have none)."""
    est = casest.estimate(scalar2.model(), scalar2.simulate(0))
    data = json.loads(est.to_json())
    data["theta"]["array"]["values"][1] = 0.2  # inside b's box [0, 0.5]
    with pytest.raises(casest.ResultFileError, match="changed after casest wrote it"):
        Estimate.from_json(json.dumps(data))
    del data["content_sha256"]
    assert Estimate.from_json(json.dumps(data)).theta[1] == 0.2
    assert Estimate.from_json(est.to_json()).theta[1] == est.theta[1]
