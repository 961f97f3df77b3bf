#!/usr/bin/env python3
"""Monte-Carlo campaign of the residual verdict: false alarms, coloured noise told apart from a
model error, and the diagnosis of what the model lacks.

    python3 scripts/campaigns/residual_verdict.py [--seeds 400] [--parts alarms coloured errors]
                                                  [--jobs 2] [--out residual_verdict.jsonl]
    (parts: alarms coloured errors frequency)

Records (each seed its own generator, ``numpy.random.default_rng([seed, case tag])``): signals
``x_1 ... x_S``, each an AR(1) sequence with coefficient 0.5 (``x_1`` scaled by 0.5), and for the
error cases ``x`` an AR(1) with coefficient 0.9 (scaled by 0.5) and ``u`` white. Outputs

    z_j = a_j sin(c_j x_1) + b_j x_(j + 1) + v_j       (a_j = 1.5, c_j = 1.2, b_j = 0.7)

(``x_(j + 1)`` left out where S = 1); the other signals are measured but do not enter (a test
against each). The noise ``v_j`` has std 10 % of the noiseless output's spread.

- ``alarms``: the right model, white noise, (S, outputs) in (1, 1), (10, 1), (100, 1), (10, 3)
  and N in 100, 1000, 10000: the rate of any other outcome than trusted (target: at most 5 %
  plus two Monte-Carlo std).
- ``coloured``: the right model (S = 2, one output, N = 1000), AR(1) noise with coefficient
  0.5 and 0.9 (unit variance, scaled as above): the rate of "coloured noise" (target >= 90 %),
  of "model error" (<= 10 %), and the coverage of +/- 1 colored-residual std over every
  parameter (target 60-76 %, nominal 68.3 %).
- ``errors``: N = 1000, white noise; the model ``a sin(c x) + b u`` fitted to records with a
  missing term (``0.5 u^2`` added), with ``x`` lagged by 3 samples, and with a step of one noise
  std in the output from 60 % of the record on: the rate of "model error" (>= 90 %), the lag
  diagnosed within 2 std of 3 (>= 90 %), the missing term named ``u^2`` (>= 80 %).
- ``frequency``: the frequency-domain output error of ``models/short_period.py`` (its 3-2-1-1
  and doublet record, 20 s at 50 Hz, 40 frequencies 0.05-2 Hz) with white noise (false alarms),
  AR(1) noise of coefficient 0.5 and 0.9 at the model file's noise std (coloured noise, coverage
  of +/- 1 std over the five derivatives), and the elevator seen by the aircraft 3 samples
  (60 ms) after the recorded one (model error, the delay within 2 std of 3 samples).

Each finished run is appended to ``--out`` (JSON lines, one write each); a later call with the
same file skips the runs already there (resume). The table gives each rate with its Monte-Carlo
standard error ``sqrt(p (1 - p) / n)``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402
from scipy.signal import lfilter  # noqa: E402

import casest  # noqa: E402
from journal import append, load  # noqa: E402
from casest.status import DiagnosisCode, TrustCode  # noqa: E402

ALARM_SHAPES = ((1, 1), (10, 1), (100, 1), (10, 3))
ALARM_LENGTHS = (100, 1000, 10000)
COLOURS = (0.5, 0.9)
ERRORS = ("term", "lag", "step")
TRUE = dict(a=1.5, c=1.2, b=0.7)
FREQUENCY_CASES = ("white", 0.5, 0.9, "lag")
SHORT_PERIOD = casest.load_model_file("short_period")
#: the frequency domain's band: 0.05-2 Hz on the record's frequency grid
BAND = 2 * np.pi * np.arange(1, 41) / SHORT_PERIOD.DURATION


def static_model(n_signals: int, n_outputs: int) -> casest.Model:
    """``z_j = a_j sin(c_j x_1) + b_j x_(j+1)`` over signals ``x_1 ... x_S``."""
    x = [ca.SX.sym(f"x{i + 1}") for i in range(n_signals)]
    parameters, outputs = [], {}
    for j in range(n_outputs):
        a, c = ca.SX.sym(f"a{j}"), ca.SX.sym(f"c{j}")
        parameters += [casest.Parameter(f"a{j}", lb=-5, ub=5), casest.Parameter(f"c{j}", lb=0.1, ub=3)]
        expression = a * ca.sin(c * x[0])
        if n_signals > 1:
            b = ca.SX.sym(f"b{j}")
            parameters.append(casest.Parameter(f"b{j}"))
            expression = expression + b * x[1 + j % (n_signals - 1)]
        outputs[f"z{j}"] = expression
    return casest.Model(parameters, [f"x{i + 1}" for i in range(n_signals)], outputs, name="campaign_static")


def _ar1(rng, rho: float, n: int) -> np.ndarray:
    return lfilter([1.0], [1.0, -rho], rng.standard_normal(n)) * np.sqrt(1.0 - rho**2)


def static_record(model, n_signals: int, n_outputs: int, N: int, rng, rho: float = 0.0):
    """The right model's record with AR(rho) noise at 10 % of each output's spread; the truth."""
    signals = np.column_stack([_ar1(rng, 0.5, N) * (0.5 if i == 0 else 1.0) for i in range(n_signals)])
    truth = {}
    for j in range(n_outputs):
        truth.update({f"a{j}": TRUE["a"], f"c{j}": TRUE["c"]})
        if n_signals > 1:
            truth[f"b{j}"] = TRUE["b"]
    clean = model.predict(model.vector(truth), signals)
    noisy = clean + 0.1 * np.std(clean, axis=0) * np.column_stack([_ar1(rng, rho, N) for _ in range(n_outputs)])
    columns = {f"x{i + 1}": signals[:, i] for i in range(n_signals)}
    columns.update({name: noisy[:, j] for j, name in enumerate(model.output_names)})
    return casest.Dataset(model, columns), truth


def error_model() -> casest.Model:
    a, b, c, x, u = (ca.SX.sym(n) for n in ("a", "b", "c", "x", "u"))
    return casest.Model([casest.Parameter("a", lb=-5, ub=5), casest.Parameter("b"), casest.Parameter("c", lb=0.1, ub=3)],
                        ["x", "u"], {"z": a * ca.sin(c * x) + b * u}, name="campaign_error")


def error_record(kind: str, N: int, rng):
    """A record the model ``a sin(c x) + b u`` lacks something of (module docstring)."""
    x = lfilter([1.0], [1.0, -0.9], rng.standard_normal(N + 10)) * 0.5
    u = rng.standard_normal(N)
    seen = x[7:N + 7] if kind == "lag" else x[10:N + 10]  # lag: the output follows x by 3 samples
    clean = TRUE["a"] * np.sin(TRUE["c"] * seen) + TRUE["b"] * u + (0.5 * u**2 if kind == "term" else 0.0)
    std = 0.1 * np.std(clean)
    z = clean + std * rng.standard_normal(N)
    if kind == "step":
        z[int(0.6 * N):] += std
    return casest.Dataset(error_model(), {"x": x[10:N + 10], "u": u, "z": z})


def short_period_record(case, rng):
    """The short-period record of the ``frequency`` part (module docstring) and the truth."""
    sp = SHORT_PERIOD
    t = np.arange(int(sp.DURATION * sp.RATE) + 1) / sp.RATE
    fine, exact = sp.model(), sp.model(substeps=8)
    shift = 3 / sp.RATE if case == "lag" else 0.0
    zeros = np.zeros_like(t)
    _, clean = exact.simulate(dict(sp.TRUTH), exact.dataset({"t": t, "delta_e": sp.elevator(t - shift),
                                                             **{n: zeros for n in fine.output_names}}))
    rho = case if isinstance(case, float) else 0.0
    noise = np.column_stack([_ar1(rng, rho, t.size) for _ in fine.output_names])
    z = clean + noise * np.array([sp.NOISE_STD[n] for n in fine.output_names])
    return fine.dataset({"t": t, "delta_e": sp.elevator(t), **{n: z[:, j] for j, n in enumerate(fine.output_names)}})


def frequency_run(case, seed: int) -> tuple:
    """One frequency-domain fit: its estimate and the row's own fields."""
    rng = np.random.default_rng([seed, 4, FREQUENCY_CASES.index(case)])
    model = SHORT_PERIOD.model()
    est = casest.frequency_domain_estimate(model, short_period_record(case, rng), BAND)
    acting = [i for i, n in enumerate(est.parameter_names) if n not in est.held]
    fields = {"covered": [bool(abs(est.theta[i] - SHORT_PERIOD.TRUTH[est.parameter_names[i]]) < est.std[i])
                          for i in acting]}
    d = est.diagnosis
    fields.update(diagnosis=None if d is None else d.code.value, value=None if d is None else d.value,
                  std=None if d is None else d.std)
    return est, fields


def run(job: tuple) -> dict:
    """One run: ``(part, case, seed)`` -> its row."""
    part, case, seed = job
    warnings.simplefilter("ignore")
    t0 = time.process_time()
    row = {"part": part, "case": case, "seed": seed}
    if part == "frequency":
        est, fields = frequency_run(case, seed)
        row.update(fields)
    elif part == "errors":
        rng = np.random.default_rng([seed, 3, ERRORS.index(case)])
        est = casest.estimate(error_model(), error_record(case, 1000, rng))
        d = est.diagnosis
        row.update(diagnosis=None if d is None else d.code.value, term=None if d is None else d.term,
                   value=None if d is None else d.value, std=None if d is None else d.std)
    else:
        if part == "alarms":
            S, ny, N = case
            rho, rng = 0.0, np.random.default_rng([seed, 1, S, ny, N])
        else:
            S, ny, N, rho = 2, 1, 1000, case
            rng = np.random.default_rng([seed, 2, int(round(100 * rho))])
        model = static_model(S, ny)
        data, truth = static_record(model, S, ny, N, rng, rho)
        est = casest.estimate(model, data)
        std = est.std_choice().std
        row["covered"] = [bool(abs(v - truth[n]) < s) for n, v, s in zip(est.parameter_names, est.theta, std)]
    row.update(outcome=est.conclusion()[0].value, cpu=time.process_time() - t0)
    return row


def jobs(parts, seeds: int) -> list:
    """Every ``(part, case, seed)`` of the campaign."""
    out = []
    for seed in range(seeds):
        if "alarms" in parts:
            out += [("alarms", (S, ny, N), seed) for S, ny in ALARM_SHAPES for N in ALARM_LENGTHS]
        if "coloured" in parts:
            out += [("coloured", rho, seed) for rho in COLOURS]
        if "errors" in parts:
            out += [("errors", kind, seed) for kind in ERRORS]
        if "frequency" in parts:
            out += [("frequency", case, seed) for case in FREQUENCY_CASES]
    return out


def _rate(flags) -> str:
    flags = np.asarray(flags, dtype=float)
    if flags.size == 0:
        return "-"
    p = float(flags.mean())
    return f"{100 * p:.1f} % +- {100 * np.sqrt(max(p * (1 - p), 1e-12) / flags.size):.1f}"


def table(rows: list) -> str:
    """The campaign's table (markdown)."""
    lines = ["| part | case | runs | rate | second figure | third figure |", "|---|---|---|---|---|---|"]
    key = lambda r: json.dumps(r["case"])  # noqa: E731
    for part in ("alarms", "coloured", "errors", "frequency"):
        own = [r for r in rows if r["part"] == part]
        for case in sorted({key(r) for r in own}, key=lambda c: (len(c), c)):
            runs = [r for r in own if key(r) == case]
            outcome = [r["outcome"] for r in runs]
            if part == "alarms":
                S, ny, N = json.loads(case)
                lines.append(f"| false alarms | S = {S}, outputs = {ny}, N = {N} | {len(runs)} | not trusted "
                             f"{_rate([o != TrustCode.TRUSTED.value for o in outcome])} | model error "
                             f"{_rate([o == TrustCode.MODEL_ERROR.value for o in outcome])} | |")
            elif part == "coloured":
                covered = [c for r in runs for c in r["covered"]]
                lines.append(f"| coloured noise | AR(1) {json.loads(case)} | {len(runs)} | coloured noise "
                             f"{_rate([o == TrustCode.COLOURED_NOISE.value for o in outcome])} | model error "
                             f"{_rate([o == TrustCode.MODEL_ERROR.value for o in outcome])} | +/- 1 colored std "
                             f"covers {_rate(covered)} |")
            elif part == "frequency":
                lines.append(_frequency_line(json.loads(case), runs))
            else:
                kind = json.loads(case)
                named = {"lag": [r["diagnosis"] == DiagnosisCode.LAG.value and abs(r["value"] - 3) < 2 * r["std"]
                                 for r in runs],
                         "term": [r["diagnosis"] == DiagnosisCode.TERM.value and r["term"] == "u^2" for r in runs],
                         "step": [r["diagnosis"] == DiagnosisCode.STEP.value for r in runs]}[kind]
                what = {"lag": "lag within 2 std of 3", "term": "u^2 named", "step": "step named"}[kind]
                lines.append(f"| model error | {kind} | {len(runs)} | model error "
                             f"{_rate([o == TrustCode.MODEL_ERROR.value for o in outcome])} | {what} {_rate(named)} | |")
    return "\n".join(lines)


def _frequency_line(case, runs: list) -> str:
    """The table's line of one case of the frequency domain."""
    outcome = [r["outcome"] for r in runs]
    not_trusted = _rate([o != TrustCode.LOCAL.value for o in outcome])
    coloured = _rate([o == TrustCode.COLOURED_NOISE.value for o in outcome])
    error = _rate([o == TrustCode.MODEL_ERROR.value for o in outcome])
    covered = _rate([c for r in runs for c in r["covered"]])
    if case == "white":
        return f"| frequency domain | white noise | {len(runs)} | not trusted {not_trusted} | model error {error} | +/- 1 std covers {covered} |"
    if case == "lag":
        named = _rate([r["diagnosis"] == DiagnosisCode.LAG.value and abs(r["value"] - 3) < 2 * r["std"] for r in runs])
        return f"| frequency domain | input 3 samples late | {len(runs)} | model error {error} | lag within 2 std of 3 {named} | |"
    return (f"| frequency domain | AR(1) {case} | {len(runs)} | coloured noise {coloured} | model error {error} | "
            f"+/- 1 colored std covers {covered} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=400, help="runs of each case (seeds 0 ... n-1)")
    parser.add_argument("--parts", nargs="+", default=["alarms", "coloured", "errors", "frequency"],
                        choices=["alarms", "coloured", "errors", "frequency"])
    parser.add_argument("--jobs", type=int, default=2, help="worker processes")
    parser.add_argument("--out", default="residual_verdict.jsonl", help="the journal (JSON lines; resumed when it exists)")
    args = parser.parse_args(argv)
    rows = load(args.out)
    done = {(r["part"], json.dumps(r["case"]), r["seed"]) for r in rows}
    todo = [j for j in jobs(args.parts, args.seeds) if (j[0], json.dumps(j[1]), j[2]) not in done]
    print(f"{len(rows)} runs in {args.out}, {len(todo)} to go", flush=True)
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        for k, row in enumerate(pool.map(run, todo, chunksize=4)):
            append(args.out, row)
            rows.append(row)
            if (k + 1) % 100 == 0:
                print(f"{k + 1} of {len(todo)} done", flush=True)
    print(table([r for r in rows if r["part"] in args.parts and r["seed"] < args.seeds]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
