#!/usr/bin/env python3
"""Named bad inputs and faults through casest's APIs, one line each with its class.

    python3 scripts/campaigns/bad_input_cases.py [--only SUBSTRING]

Each case is a call that casest must answer clearly: ``clear`` (a casest error whose message
names the problem, or a coded note / warning on a result that is not trusted), ``silent`` (a
result with nothing said), ``crash`` (an exception that is not a casest error). The list holds the
cases of the reliability reviews (bounded amplitudes from x = 0, output paths that are not files,
frequency bands, sigma-point ranges, data frames' indexes, profile intervals' inputs, the Kalman
filter's measurements, result files, duplicate options, ...), so the next review starts from it.
Exit status 1 when any case is not ``clear``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))

import casadi as ca  # noqa: E402

import casest  # noqa: E402


def _scalar2():
    m = casest.load_model_file("scalar2")
    return m, m.model(), m.simulate(seed=0)


def _exponentials():
    x = np.linspace(0, 300, 33)
    y = 0.375 + 1.936 * np.exp(-0.0129 * x) - 1.465 * np.exp(-0.0221 * x)
    b = [ca.SX.sym(f"b{i}") for i in range(1, 6)]
    xs = ca.SX.sym("x")
    h = b[0] + b[1] * ca.exp(-xs * b[3]) + b[2] * ca.exp(-xs * b[4])
    params = [casest.Parameter(f"b{i}", lb=-1e3, ub=1e3, nominal=0.0) for i in (1, 2, 3)] + \
             [casest.Parameter(f"b{i}", lb=1e-4, ub=10.0, nominal=1.0) for i in (4, 5)]
    m = casest.Model(params, [casest.Signal("x")], {"y": h})
    return casest.estimate(m, casest.Dataset(m, {"x": x, "y": y + 1e-3 * np.random.default_rng(0).standard_normal(33)}))


def _fifo(folder):
    path = os.path.join(folder, "pipe")
    os.mkfifo(path)
    casest.data.atomic_write_text(path, "x")


def _short_period_frequency(band):
    sp = casest.load_model_file("short_period")
    return casest.frequency_domain_estimate(sp.model(), sp.simulate(0), band)


def _ukf(**options):
    m = casest.load_model_file("short_period")
    model = m.model()
    return casest.UnscentedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, [m.NOISE_STD[n] ** 2 for n in model.output_names],
                                        np.eye(2) * 1e-6, **options)


def _kalman_update(value):
    from casest.state.kalman import KalmanFilter

    return KalmanFilter(Phi=[[1.0]], C=[[1.0]], Q=[[0.01]], R=[[0.1]], x0=[0.0], P0=[[1.0]]).update([value])


def _edited_result(field, value):
    m = casest.load_model_file("scalar1")
    data = json.loads(casest.estimate(m.model(), m.simulate(seed=0)).to_json())
    data[field] = value
    return casest.Estimate.from_json(json.dumps(data))


def _profile(theta=None, R=None):
    from casest.two_stage.profile import profile_intervals

    _, model, data = _scalar2()
    problem = casest.Problem(model, data)
    est = casest.estimate(problem)
    return profile_intervals(problem, est.theta if theta is None else theta, est.R if R is None else R)


def _cli(*arguments):
    from casest.apps.cli import main

    code = main(list(arguments))
    if code == 2:
        raise casest.OptionError("the command line refused it (exit 2)")
    return code


def cases(folder: str) -> dict:
    """Case name -> (class of the input, the call)."""
    _, model, data = _scalar2()
    return {
        "bounded amplitudes, exponentials from x = 0": ("numerics", _exponentials),
        "output path is a FIFO": ("output path", lambda: _fifo(folder)),
        "output path is a device": ("output path", lambda: casest.data.atomic_write_text("/dev/null", "x")),
        "frequency band past Nyquist": ("frequency domain", lambda: _short_period_frequency(np.linspace(1, 400, 30))),
        "one frequency for five parameters": ("frequency domain", lambda: _short_period_frequency(np.array([2.0]))),
        "empty frequency band": ("frequency domain", lambda: _short_period_frequency(np.array([]))),
        "UKF alpha = 1e6": ("filters", lambda: _ukf(alpha=1e6)),
        "UKF kappa = 1e12": ("filters", lambda: _ukf(kappa=1e12)),
        "Kalman update 1e200": ("filters", lambda: _kalman_update(1e200)),
        "Kalman update inf": ("filters", lambda: _kalman_update(np.inf)),
        "KnownNoise of a list": ("noise", lambda: casest.KnownNoise([0.09])),
        "result file success = 'yes'": ("result files", lambda: _edited_result("success", "yes")),
        "result file n_samples = -5": ("result files", lambda: _edited_result("n_samples", -5)),
        "result file from a newer casest": ("result files", lambda: _edited_result("format", "casest.Estimate/9")),
        "profile intervals from NaN theta": ("profile", lambda: _profile(theta=np.full(4, np.nan))),
        "profile intervals with R = -0.09": ("profile", lambda: _profile(R=[-0.09])),
        "estimate covariance='hessain'": ("front door", lambda: casest.estimate(model, data, covariance="hessain")),
        "--fix a=1 --fix a=2": ("command line", lambda: _cli("solve", "scalar2", "--quick", "--quiet", "--fix", "a=1",
                                                              "--fix", "a=2")),
        "State('x', None)": ("models", lambda: casest.State("x", None)),
        "SweepSettings(task_size=1.5)": ("settings", lambda: casest.SweepSettings(task_size=1.5)),
        "progress='loud'": ("front door", lambda: casest.estimate(model, data, progress="loud")),
    }


def classify(call) -> tuple[str, str]:
    """``(class, what was said)`` of one case."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = call()
        except casest.CasestError as err:
            return "clear", str(err).splitlines()[0][:160]
        except Exception as err:  # noqa: BLE001 - the point is to see any other exception
            return "crash", f"{type(err).__name__}: {err}"[:160]
    conclusion = getattr(result, "conclusion", None)
    if conclusion is not None:
        code, reason = conclusion()
        if code is not casest.status.TrustCode.TRUSTED:
            return "clear", f"{code.value}: {reason[:140]}"
    if caught:
        return "clear", f"warning: {str(caught[0].message)[:150]}"
    return "silent", "no error, no note"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="run the cases whose name holds this text")
    args = parser.parse_args(argv)
    bad = 0
    with tempfile.TemporaryDirectory(prefix="casest_bad_inputs_") as folder:
        for name, (kind, call) in cases(folder).items():
            if args.only and args.only not in name:
                continue
            outcome, said = classify(call)
            bad += outcome != "clear"
            print(f"{outcome:6s} | {kind:16s} | {name:40s} | {said}", flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
