"""Mutations of a valid CSV file and model file for the command line, and the rule every run must obey.

Used by ``tests/test_fuzz.py`` (a bounded number of examples in the default suite) and by
``scripts/campaigns/fuzz_inputs.py`` (a longer campaign). The base case is the paper's scalar example 1
(``models/scalar1.py``, simulated with seed 3, truth a = 1, b = 0.1, c = 1). A mutated run
must end in one of:

- exit 0 or 4 with a report: if its conclusion says "trust it", every parameter lies within
  ``TRUST_K`` of its stated std of the simulated truth;
- exit 1 (stage 2 did not converge: said so);
- exit 2 (a user error: one or two lines, no traceback).

Never exit 3 (a casest defect) and never a traceback.
"""

from __future__ import annotations

import os
import re

from hypothesis import strategies as st

TRUTH = {"a": 1.0, "b": 0.1, "c": 1.0}
TRUST_K = 4.0  # std: a "trust it" estimate beyond this from the truth is a silent wrong answer

MODEL_TEMPLATE = '''import casadi as ca
import casest


def model():
    a, b, c, eta = (ca.SX.sym(n) for n in ("a", "b", "c", "eta"))
    return casest.Model(
        parameters=[
            casest.Parameter("a", {a_args}),
            casest.Parameter("b", {b_args}),
            casest.Parameter("c", {c_args}),
        ],
        signals=[casest.Signal("eta", unit="{eta_unit}")],
        outputs={{"z": (1 + a) * ca.cos(eta + b) + c}},
        name="fuzzed",
    )
'''

BASE_ARGS = {"a_args": 'nominal=0.0, prior=casest.Gaussian(0.0, 1.0)', "b_args": 'lb=0.0, ub=0.2, nominal=0.0, unit="rad"',
             "c_args": 'nominal=0.0, prior=casest.Gaussian(0.0, 1.0)', "eta_unit": "rad"}

CELLS = ["", "abc", "1,5", "nan", "NaN", "inf", "-inf", "1e400", "1e200", "-1e200", "1e-200", "0x10", "  ", "1.0.0",
         "\u00e9", "--1", "1e", "3 4"]
HEADERS = ["eta", "z", "eta [rad]", "eta [deg]", "eta [furlong]", "z [m]", "eta [", "eta]", "Eta", "zz", "", "eta [rad",
           "\u00e9ta", "eta [1/s]"]
ARGS = ["lb=1.0, ub=0.0", "lb=0.5, ub=0.5", "nominal=5.0, lb=0.0, ub=1.0", "lb=float('nan')", "ub=float('inf')",
        "nominal=float('inf')", "prior=casest.Gaussian(0.0, -1.0)", "prior=casest.LogUniform(), lb=-1.0, ub=1.0",
        "scale=0.0", "fixed=True", "lb=-1e300, ub=1e300", "unit=3"]


def base_rows(simulate) -> tuple[list, list]:
    """The header and rows of the base CSV (scalar example 1, seed 3)."""
    data = simulate(3)
    rows = [[repr(float(e)), repr(float(z))] for e, z in zip(data.column("eta"), data.column("z"))]
    return ["eta [rad]", "z"], rows


@st.composite
def mutations(draw):
    """A list of (kind, details) mutations, applied in order to the base CSV and model file."""
    kinds = st.sampled_from(["delete_column", "duplicate_column", "rename_column", "cell", "header", "encoding",
                             "short_row", "extra_column", "delimiter", "model_args", "eta_unit", "empty_rows",
                             "constant_signal", "scale_output"])
    out = []
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(kinds)
        if kind == "cell":
            out.append((kind, (draw(st.integers(0, 99)), draw(st.integers(0, 1)), draw(st.sampled_from(CELLS)))))
        elif kind in ("header", "rename_column"):
            out.append((kind, (draw(st.integers(0, 1)), draw(st.sampled_from(HEADERS)))))
        elif kind == "model_args":
            out.append((kind, (draw(st.sampled_from(["a_args", "b_args", "c_args"])), draw(st.sampled_from(ARGS)))))
        elif kind == "eta_unit":
            out.append((kind, draw(st.sampled_from(["", "deg", "rad", "m/s", "furlong"]))))
        elif kind == "encoding":
            out.append((kind, draw(st.sampled_from(["latin-1-accent", "utf-16", "utf-8-sig", "binary"]))))
        elif kind == "delimiter":
            out.append((kind, draw(st.sampled_from([";", "\t", " ", "|"]))))
        elif kind in ("short_row", "empty_rows"):
            out.append((kind, draw(st.integers(0, 99))))
        elif kind == "scale_output":
            out.append((kind, draw(st.sampled_from([1e-160, 1e160, 0.0, -1.0]))))
        else:
            out.append((kind, draw(st.integers(0, 1))))
    return out


def apply(header: list, rows: list, muts: list) -> tuple[bytes, str, dict]:
    """The mutated CSV file (bytes), model file (text) and the truth of the mutated data (a
    scaled output z' = f z has a' = f (1 + a) - 1, c' = f c)."""
    header, rows = list(header), [list(r) for r in rows]
    args, delimiter, encoding = dict(BASE_ARGS), ",", "utf-8"
    gain = 1.0  # the product of the output's scalings: the truth is computed from it once (no cancellation)
    for kind, d in muts:
        if kind == "delete_column" and len(header) > 1:
            d = min(d, len(header) - 1)
            del header[d]
            for r in rows:
                if d < len(r):
                    del r[d]
        elif kind == "duplicate_column" and header:
            j = min(d, len(header) - 1)
            header.append(header[j])
            for r in rows:
                r.append(r[j] if j < len(r) else "")
        elif kind in ("rename_column", "header") and header:
            header[min(d[0], len(header) - 1)] = d[1]
        elif kind == "cell" and rows:
            row = rows[min(d[0], len(rows) - 1)]
            if row:
                row[min(d[1], len(row) - 1)] = d[2]
        elif kind == "extra_column":
            header.append("note")
            for r in rows:
                r.append("x")
        elif kind == "short_row" and rows:
            rows[min(d, len(rows) - 1)] = rows[min(d, len(rows) - 1)][:1]
        elif kind == "empty_rows":
            rows = rows[:d]
        elif kind == "constant_signal" and header:
            for r in rows:
                if r:
                    r[0] = "2.0"
        elif kind == "scale_output":
            gain *= d
            # every column of the output (a duplicated one too: a later deletion may keep either)
            for j in [k for k, name in enumerate(header) if name == "z"] or [1]:
                for r in rows:
                    if len(r) > j:
                        try:
                            r[j] = repr(float(r[j]) * d)
                        except ValueError:
                            pass
        elif kind == "delimiter":
            delimiter = d
        elif kind == "model_args":
            args[d[0]] = d[1]
        elif kind == "eta_unit":
            args["eta_unit"] = d
        elif kind == "encoding":
            encoding = d
    truth = {"a": gain * (1 + TRUTH["a"]) - 1, "b": TRUTH["b"], "c": gain * TRUTH["c"]}
    text = "\n".join(delimiter.join(r) for r in [header] + rows) + "\n"
    if encoding == "latin-1-accent":
        raw = text.replace("z", "z\u00e9", 1).encode("latin-1", errors="replace")
    elif encoding == "binary":
        raw = b"\x00\x01\x02" + text.encode()
    else:
        raw = text.encode(encoding)
    return raw, MODEL_TEMPLATE.format(**args), truth


def check_outcome(status: int, out: str, err: str, json_path: str, truth: dict = TRUTH) -> None:
    """The rule of the module docstring; raises AssertionError naming what was broken."""
    assert "Traceback" not in err and "Traceback" not in out, err[-2000:]
    assert status in (0, 1, 2, 4), f"exit {status}: {err[-2000:]}"
    if status == 2:
        lines = [line for line in err.strip().splitlines() if not line.startswith("casest: warning")]
        assert 1 <= len(lines) <= 2, err
        return
    conclusion = out.split("[[Conclusion]]")[-1].split("\n")[0] if "[[Conclusion]]" in out else ""
    if status == 0 and conclusion.strip().startswith("trust it") and os.path.exists(json_path):
        import casest

        est = casest.Estimate.from_json(json_path)
        for name, value, std in zip(est.parameter_names, est.theta, est.std):
            if name in est.fixed_parameters:
                continue  # held, not estimated
            assert abs(value - truth[name]) <= TRUST_K * std, (
                f"'trust it' but {name} = {value} is {abs(value - truth[name]) / std:.1f} std from the truth {truth[name]}")


def run_case(cli, capsys, folder, header, rows, muts) -> int:
    """Write the mutated files, run ``casest solve`` on them, check the outcome; returns the exit status."""
    raw, model_text, truth = apply(header, rows, muts)
    csv_path, model_path = os.path.join(folder, "data.csv"), os.path.join(folder, "fuzzed.py")
    json_path = os.path.join(folder, "estimate.json")
    for path in (csv_path, model_path, json_path):
        if os.path.exists(path):
            os.remove(path)
    with open(csv_path, "wb") as fh:
        fh.write(raw)
    with open(model_path, "w", encoding="utf-8") as fh:
        fh.write(model_text)
    status = cli(["solve", model_path, "--data", csv_path, "--quick", "--quiet", "--json", json_path])
    captured = capsys()
    check_outcome(status, captured[0], captured[1], json_path, truth)
    return status


def summary_key(status: int, out: str) -> str:
    return {0: "result", 1: "not converged", 2: "user error", 4: "caution"}.get(status, f"exit {status}") + (
        " (trust it)" if re.search(r"\[\[Conclusion\]\] trust it", out) else "")
