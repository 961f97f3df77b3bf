#!/usr/bin/env python3
"""Named bad inputs and faults through casest's APIs, one line each with its class.

    python3 scripts/campaigns/bad_input_cases.py [--only SUBSTRING]

Each case is a call that casest must answer clearly: ``clear`` (a casest error whose message
names the problem, or a coded note / warning on a result that is not trusted), ``handled`` (the
input is right after all and was dealt with correctly, checked by the case: an output appended to
the file a shell redirects), ``silent`` (a result with nothing said), ``crash`` (an exception that
is not a casest error, or a process that dies), ``hang`` (no answer in :data:`TIME_LIMIT`), ``memory``
(past :data:`MEMORY_LIMIT`): each case runs in a process of its own under both limits. The list holds the
cases of the reliability reviews (bounded amplitudes from x = 0, output paths that are not files,
frequency bands, sigma-point ranges, data frames' indexes, profile intervals' inputs, the Kalman
filter's measurements, result files, duplicate options, ...), so the next review starts from it.
Exit status 1 when any case is neither ``clear`` nor ``handled``.
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


from bad_input_features import Handled, feature_cases  # noqa: E402

#: each case runs in a process of its own under these limits: a case past them is a hang or runs out of memory
TIME_LIMIT = 300.0  # seconds
MEMORY_LIMIT = 6 * 2**30  # bytes of address space


def _appended_through_descriptor(folder):
    """An output written through ``/proc/self/fd/N`` of a file opened for appending keeps the file's lines."""
    path = os.path.join(folder, "log.txt")
    with open(path, "w") as fh:
        fh.write("earlier line\n")
    with open(path, "a") as fh:
        casest.data.atomic_write_text(f"/proc/self/fd/{fh.fileno()}", "{}\n")
    with open(path) as fh:
        text = fh.read()
    if text != "earlier line\n{}\n":
        raise AssertionError(f"the file now holds {text!r}")
    return Handled("appended after the earlier line; nothing replaced")


def _cli_json_appended(folder):
    """``casest solve scalar2 --quick --quiet --json /dev/stdout >> log.txt``: the earlier lines stay."""
    import subprocess

    path = os.path.join(folder, "cli_log.txt")
    with open(path, "w") as fh:
        fh.write("earlier line\n")
    with open(path, "a") as out:
        run = subprocess.run([sys.executable, "-m", "casest", "solve", "scalar2", "--quick", "--quiet", "--json",
                              "/dev/stdout"], stdout=out, stderr=subprocess.DEVNULL, timeout=600, cwd=folder)
    with open(path) as fh:
        text = fh.read()
    if run.returncode or not text.startswith("earlier line\n{"):
        raise AssertionError(f"exit {run.returncode}; the file starts {text[:40]!r}")
    return Handled("the JSON alone appended after the earlier line (the report on standard error)")


def _export(folder, sub, name="fl", prepare=None, force=False):
    """The short-period EKF exported into ``folder/sub`` (after ``prepare(path)``)."""
    sp = casest.load_model_file("short_period")
    model = sp.model()
    ekf = casest.ExtendedKalmanFilter(model, model.nominal, np.zeros(2), np.ones(model.n_outputs), np.eye(2))
    path = os.path.join(folder, sub)
    os.makedirs(path, exist_ok=True)
    if prepare is not None:
        prepare(path)
    return casest.export_c(ekf, path, name=name, force=force)


def _two_exports(folder):
    """Two exports into one folder: the README keeps both sections."""
    _export(folder, "two", "first")
    _export(folder, "two", "second")
    with open(os.path.join(folder, "two", "README.md")) as fh:
        text = fh.read()
    if "# first" not in text or "# second" not in text:
        raise AssertionError("a README section was lost")
    return Handled("README.md holds both exports' sections")


def _users_readme(path):
    with open(os.path.join(path, "README.md"), "w") as fh:
        fh.write("my notes\n")


def _readme_link(path):
    target = os.path.join(os.path.dirname(path), "precious.md")
    with open(target, "w") as fh:
        fh.write("keep\n")
    os.symlink(target, os.path.join(path, "README.md"))


def _named_fifo(folder, name):
    path = os.path.join(folder, name)
    if not os.path.exists(path):
        os.mkfifo(path)
    return path


def _short_period_frequency(band):
    sp = casest.load_model_file("short_period")
    return casest.frequency_domain_estimate(sp.model(), sp.simulate(0), band)


def _ukf(**options):
    m = casest.load_model_file("short_period")
    model = m.model()
    return casest.UnscentedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, [m.NOISE_STD[n] ** 2 for n in model.output_names],
                                        np.eye(2) * 1e-6, **options)


def _kalman_update(value):
    from casest.filters.kalman import KalmanFilter

    return KalmanFilter(Phi=[[1.0]], C=[[1.0]], Q=[[0.01]], R=[[0.1]], x0=[0.0], P0=[[1.0]]).update([value])


def _edited_result(field, value):
    m = casest.load_model_file("scalar1")
    data = json.loads(casest.estimate(m.model(), m.simulate(seed=0)).to_json())
    data[field] = value
    return casest.Estimate.from_json(json.dumps(data))


def _edited_array(field, edit):
    """A saved estimate whose array ``field`` was edited by ``edit`` (the file's own encoding kept)."""
    from casest.estimation.result_schema import decode_field, encode_field

    m = casest.load_model_file("scalar1")
    data = json.loads(casest.estimate(m.model(), m.simulate(seed=0)).to_json())
    data[field] = encode_field(edit(np.array(decode_field(data[field]), dtype=float)))
    return casest.Estimate.from_json(json.dumps(data))


def _set(index, value):
    def edit(arr):
        arr[index] = value
        return arr
    return edit


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


def _step_calibration():
    """A static two-parameter calibration recorded in time, built from plain arrays, with a step
    in the sensor at 60 % of the record (a magnet taken away)."""
    rng = np.random.default_rng(3)
    N = 500
    x = rng.uniform(-1, 1, N)
    y = 2.0 * x + 0.5 + np.where(np.arange(N) >= 300, 0.3, 0.0) + 0.05 * rng.standard_normal(N)
    xs, a, b = ca.SX.sym("x"), ca.SX.sym("a"), ca.SX.sym("b")
    model = casest.Model([casest.Parameter("a", -10, 10, 1.0), casest.Parameter("b", -10, 10, 0.0)],
                         [casest.Signal("x")], {"y": a * xs + b})
    return casest.estimate(model, casest.Dataset(model, {"x": x, "y": y}))


def _missing_term():
    rng = np.random.default_rng(4)
    N = 400
    x1, x2 = rng.uniform(-2, 2, N), rng.uniform(-2, 2, N)
    y = 1.5 * x1 - 0.7 * x2 + 0.2 * np.sin(3 * x2) + 0.05 * rng.standard_normal(N)
    s1, s2, a, b = ca.SX.sym("x1"), ca.SX.sym("x2"), ca.SX.sym("a"), ca.SX.sym("b")
    model = casest.Model([casest.Parameter("a", -10, 10, 1.0), casest.Parameter("b", -10, 10, 1.0)],
                         [casest.Signal("x1"), casest.Signal("x2")], {"y": a * s1 + b * s2})
    return casest.estimate(model, casest.Dataset(model, {"x1": x1, "x2": x2, "y": y}))


def _regress(columns):
    x = ca.SX.sym("x")
    return casest.regress("z", {"c": 1, "x": x}, columns)


def _ekf():
    m = casest.load_model_file("short_period")
    model = m.model()
    return m, casest.ExtendedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, [m.NOISE_STD[n] ** 2 for n in model.output_names],
                                          np.eye(2) * 1e-6, x0=np.zeros(2))


def _ekf_filter_of_a_result():
    m, ekf = _ekf()
    return ekf.filter(ekf.filter(m.simulate(0)))


def _kalman_pass(value):
    from casest.filters.kalman import KalmanFilter

    return KalmanFilter(Phi=[[1.0]], C=[[1.0]], Q=[[0.01]], R=[[0.1]], x0=[0.0], P0=[[1.0]]).filter(
        np.array([[1.0], [value], [1.0]]), compiled=False)


def _smoother(**options):
    from casest.filters import KalmanFilter, rts_smoother, single_stage_smoother

    result = KalmanFilter(Phi=[[1.0]], C=[[1.0]], Q=[[0.01]], R=[[0.1]], x0=[0.0], P0=[[1.0]]).filter(np.ones((6, 1)))
    if "k" in options:
        return single_stage_smoother(result, options["k"], [[0.01]])
    return rts_smoother(result, process_noise=options["process_noise"])


def _design(candidates=None, prior=None):
    m, model, data = _scalar2()
    default = {f"b{k}": data.subset(np.arange(20 * k, 20 * k + 20)) for k in range(5)}
    return casest.design_experiment(model, candidates or default, m.TRUTH, [0.09], budget=1e6 if candidates else 100.0,
                                    prior_information=prior)


def _journal_line(folder, line):
    from casest.apps.montecarlo import Journal

    path = os.path.join(folder, "runs.jsonl")
    with open(path, "w") as fh:
        fh.write(line + "\n")
    return Journal(path)


def _recursive_ml(**options):
    from casest.recursive import RecursiveML

    _, model, _ = _scalar2()
    return RecursiveML(model, model.nominal, [0.09], **options)


def _frame(index):
    import pandas as pd

    _, model, data = _scalar2()
    frame = pd.DataFrame({"eta": data.column("eta")[:5], "z": data.column("z")[:5]}, index=index)
    return casest.Dataset.from_dataframe(casest.load_model_file("short_period").model(), frame)


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
        "static record with a step at 60 %, from arrays": ("residuals", _step_calibration),
        "a term missing in one signal": ("residuals", _missing_term),
        "all frequencies above Nyquist": ("frequency domain", lambda: _short_period_frequency(np.linspace(400, 500, 10))),
        "regression NaN at row 5": ("equation error", lambda: _regress({"x": np.r_[np.arange(5.0), np.nan, np.arange(4.0)],
                                                                       "z": np.arange(10.0)})),
        "regression text column": ("equation error", lambda: _regress({"x": ["a"] * 10, "z": np.arange(10.0)})),
        "data frame with a RangeIndex as time": ("data frames", lambda: _frame(None)),
        "result file correlation 5.0": ("result files", lambda: _edited_array("correlation", _set((0, 1), 5.0))),
        "result file std 0": ("result files", lambda: _edited_array("std", _set(0, 0.0))),
        "result file covariance entry -1": ("result files", lambda: _edited_array("covariance", _set((1, 1), -1.0))),
        "Kalman pass (Python) 1e200": ("filters", lambda: _kalman_pass(1e200)),
        "Kalman pass (Python) -inf": ("filters", lambda: _kalman_pass(-np.inf)),
        "EKF.filter(FilterResult)": ("filters", _ekf_filter_of_a_result),
        "EKF predict_ahead(-3)": ("filters", lambda: _ekf()[1].predict_ahead(-3, 0.01)),
        "EKF update with 2 of 3 outputs": ("filters", lambda: _ekf()[1].update([1.0, 2.0], [0.0])),
        "single_stage_smoother(k=1.7)": ("smoothers", lambda: _smoother(k=1.7)),
        "single_stage_smoother(k=NaN)": ("smoothers", lambda: _smoother(k=float("nan"))),
        "rts_smoother(process_noise={...})": ("smoothers", lambda: _smoother(process_noise={"x": 0.1})),
        "RecursiveML(forgetting_rate=1.5)": ("recursive", lambda: _recursive_ml(forgetting_rate=1.5)),
        "RecursiveML(forgetting=-1)": ("recursive", lambda: _recursive_ml(forgetting=-1)),
        "RecursiveML(information0=zeros)": ("recursive", lambda: _recursive_ml(information0=np.zeros((5, 5)))),
        "SweepSettings(task_size='big')": ("settings", lambda: casest.SweepSettings(task_size="big")),
        "design: another model's candidate": ("design", lambda: _design(
            {"other": casest.load_model_file("pitot5hole").simulate(0)})),
        "design: 3 x 3 prior for 4 parameters": ("design", lambda: _design(prior=np.eye(3))),
        "design: NaN prior": ("design", lambda: _design(prior=np.full((4, 4), np.nan))),
        "--noise known:z=0.3,z=0.4": ("command line", lambda: _cli("solve", "scalar2", "--quick", "--quiet", "--noise",
                                                                    "known:z=0.3,z=0.4")),
        "campaign journal line not a run record": ("campaigns", lambda: _journal_line(folder, '{"run": 2}')),
        "--data /dev/zero": ("input path", lambda: _cli("solve", "scalar2", "--quick", "--quiet", "--data", "/dev/zero")),
        "--data /dev/urandom": ("input path", lambda: _cli("solve", "scalar2", "--quick", "--quiet", "--data",
                                                          "/dev/urandom")),
        "--data a FIFO without a writer": ("input path", lambda: _cli("solve", "scalar2", "--quick", "--quiet", "--data",
                                                                     _named_fifo(folder, "data_pipe"))),
        "Estimate.from_json(a FIFO)": ("input path", lambda: casest.Estimate.from_json(_named_fifo(folder, "json_pipe"))),
        "output through /proc/self/fd/N of a file opened to append": ("output path",
                                                                      lambda: _appended_through_descriptor(folder)),
        "--json /dev/stdout >> log.txt": ("output path", lambda: _cli_json_appended(folder)),
        "export-c --name _Bool": ("C export", lambda: _cli("export-c", "short_period", "--out",
                                                           os.path.join(folder, "bool"), "--name", "_Bool")),
        "export_c(name='__init')": ("C export", lambda: _export(folder, "init", "__init")),
        "export-c --name math": ("C export", lambda: _cli("export-c", "short_period", "--out",
                                                          os.path.join(folder, "math"), "--name", "math")),
        "export_c(name='errno')": ("C export", lambda: _export(folder, "errno", "errno")),
        "export into a folder with the user's README.md": ("C export", lambda: _export(folder, "users", "fl",
                                                                                        _users_readme)),
        "export through a README.md that is a link": ("C export", lambda: _export(folder, "link", "fl", _readme_link,
                                                                                   force=True)),
        "two exports into one folder": ("C export", lambda: _two_exports(folder)),
        **feature_cases(folder),
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
    if isinstance(result, Handled):
        return "handled", str(result)
    conclusion = getattr(result, "conclusion", None)
    if conclusion is not None:
        code, reason = conclusion()
        if code is not casest.status.TrustCode.TRUSTED:
            return "clear", f"{code.value}: {reason[:140]}"
    if caught:
        return "clear", f"warning: {str(caught[0].message)[:150]}"
    return "silent", "no error, no note"


def _classify_in_child(call, connection) -> None:
    """:func:`classify` of one case in a forked process whose address space is bounded."""
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
    try:
        connection.send(classify(call))
    except MemoryError:
        connection.send(("memory", f"past {MEMORY_LIMIT / 2**30:.0f} GiB of address space"))


def limited(call) -> tuple[str, str]:
    """:func:`classify` of one case under :data:`TIME_LIMIT` and :data:`MEMORY_LIMIT`: ``hang`` when it gives
    no answer in time (the process is killed), ``crash`` when its process dies (a signal: a bus error)."""
    import multiprocessing

    context = multiprocessing.get_context("fork")  # the case's lambda and its inputs, as they are
    receiver, sender = context.Pipe(duplex=False)
    process = context.Process(target=_classify_in_child, args=(call, sender))
    process.start()
    sender.close()
    try:
        if receiver.poll(TIME_LIMIT):
            return receiver.recv()
        return "hang", f"no answer in {TIME_LIMIT:.0f} s"
    except EOFError:
        process.join()
        return "crash", f"the case's process ended with exit code {process.exitcode} (a signal when negative)"
    finally:
        if process.is_alive():
            process.kill()
        process.join()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="run the cases whose name holds this text")
    args = parser.parse_args(argv)
    bad = 0
    with tempfile.TemporaryDirectory(prefix="casest_bad_inputs_") as folder:
        for name, (kind, call) in cases(folder).items():
            if args.only and args.only not in name:
                continue
            outcome, said = limited(call)
            bad += outcome not in ("clear", "handled")
            print(f"{outcome:6s} | {kind:16s} | {name:40s} | {said}", flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
