"""Monte-Carlo checks of the estimator on simulated data with known truth."""

from __future__ import annotations

import json as _json
import multiprocessing as _mp
import os as _os
import sys as _sys
import time as _time
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager, suppress
from dataclasses import dataclass

import numpy as np

from .._casadi.numerics import process_alive
from ..data.dataset import atomic_write_text
from ..checks import own_folder, whole_number
from ..errors import CampaignError, MissingExtraError
from ..two_stage.pipeline import estimate
from ..models.modelfile import model_file_hooks
from .campaign_journal import Journal
from .campaign_summary import runs_csv, summarize, summary_table  # noqa: F401  (summary_table: its old home)


__all__ = ["SpreadCheck", "std_against_spread"]


@dataclass
class SpreadCheck:
    """Reported standard deviations against the Monte-Carlo spread of the estimates.

    Attributes
    ----------
    names : tuple of str
    estimates : ndarray, shape (runs, n_parameters)
    reported_std : ndarray, shape (runs, n_parameters)
        NaN where a run reported none (parameter on a bound).
    truth : ndarray, shape (n_parameters,)
    ratio : ndarray, shape (n_parameters,)
        Mean reported std / sample std of the estimates.
    coverage : ndarray, shape (n_parameters,)
        Fraction of runs with |estimate - truth| <= 2 reported std (runs with a std).
    n_failed : int
        Runs whose stage 2 did not converge (excluded).
    """

    names: tuple
    estimates: np.ndarray
    reported_std: np.ndarray
    truth: np.ndarray
    ratio: np.ndarray
    coverage: np.ndarray
    n_failed: int

    def table(self) -> str:
        lines = [f"{'param':>8} {'truth':>10} {'mean est':>10} {'MC std':>10} {'mean std':>10} {'ratio':>7} {'2-sigma cov':>11}"]
        mc = np.std(self.estimates, axis=0, ddof=1)
        rep = np.nanmean(self.reported_std, axis=0)
        for i, n in enumerate(self.names):
            lines.append(
                f"{n:>8} {self.truth[i]:>10.5g} {np.mean(self.estimates[:, i]):>10.5g} {mc[i]:>10.4g} "
                f"{rep[i]:>10.4g} {self.ratio[i]:>7.3f} {100 * self.coverage[i]:>10.1f}%"
            )
        return "\n".join(lines)


def std_against_spread(module, runs: int = 200, first_seed: int = 0, **estimate_kw) -> SpreadCheck:
    """Estimate ``runs`` data sets from ``module.simulate(seed)`` and compare std with spread.

    Parameters
    ----------
    module : model-file module
        Needs ``model()``, ``simulate(seed)`` and ``TRUTH``.
    runs : int
    first_seed : int
        Seeds ``first_seed .. first_seed + runs - 1``.
    **estimate_kw
        Passed to :func:`casest.estimate`.
    """
    hooks = model_file_hooks(module)
    hooks.require("simulate", "truth", purpose="the std check")
    model = hooks.model()
    truth = model.vector(hooks.truth)
    est, std = [], []
    failed = 0
    for seed in range(first_seed, first_seed + runs):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            result = estimate(model, hooks.simulate(seed), **estimate_kw)
        if not result.success:
            failed += 1
            continue
        est.append(result.theta)
        std.append(result.std)
    est, std = np.array(est), np.array(std)
    mc = np.std(est, axis=0, ddof=1)
    ratio = np.nanmean(std, axis=0) / mc
    with np.errstate(invalid="ignore"):
        inside = np.abs(est - truth) <= 2 * std
    coverage = np.array([inside[np.isfinite(std[:, i]), i].mean() for i in range(len(truth))])
    return SpreadCheck(model.parameter_names, est, std, truth, ratio, coverage, failed)


# ============================================================================ campaigns

@dataclass(frozen=True)
class CampaignConfig:
    """What defines a campaign; a resumed campaign must have the same one.

    Attributes
    ----------
    model : str
        Path of the model file (it must define model(), simulate(seed), TRUTH and
        BENCHMARK1_STARTS; change_of_variables() enables Benchmark 2).
    first_seed : int
        Run i uses noise seed ``first_seed + i``.
    reference_starts : int
        Starts of the multi-start reference solve per run.
    covariance : {"hessian", "gauss-newton"}
        Covariance method of the proposed estimator and Benchmark 1.
    dof_correction : bool
        The degrees-of-freedom correction of their covariance.
    noise : dict of str to float, optional
        Known noise std per output given to the proposed estimator (``KnownNoise``),
        e.g. deliberately wrong, to check its conclusion line; the benchmarks then do not run.
    fixed : dict of str to float, optional
        Parameters held at these values by the proposed estimator; the benchmarks then do not run.
    model_digest : str
        SHA-256 of the model file's text: a campaign is resumed by the model's content, wherever
        the file lies (filled in by :func:`run_campaign`).
    """

    model: str
    first_seed: int = 0
    reference_starts: int = 32
    covariance: str = "hessian"
    dof_correction: bool = False
    noise: dict | None = None
    fixed: dict | None = None
    model_digest: str = ""

    def to_dict(self) -> dict:
        return dict(self.__dict__)


_MODULES: dict = {}
_MODELS: dict = {}


def _module(path: str):
    from ..models.modelfile import load_model_file

    if path not in _MODULES:
        _MODULES[path] = load_model_file(path)
    return _MODULES[path]


def _model(path: str):
    """One Model per process and file, so that built solvers are reused across runs."""
    if path not in _MODELS:
        _MODELS[path] = _module(path).model()
    return _MODELS[path]


def _method_record(problem, est, seconds: float) -> dict:
    model = problem.full_model
    inside = bool(np.all(est.theta >= model.lower_bounds) and np.all(est.theta <= model.upper_bounds))
    record = {
        "theta": [float(v) for v in est.theta],
        "std": [float(s) if np.isfinite(s) else None for s in est.std],
        "cost": float(problem.profile_cost(est.theta)),
        "success": bool(est.success),
        "in_bounds": inside,
        "seconds": float(seconds),
    }
    if hasattr(est, "conclusion"):
        record["conclusion"] = est.conclusion()[0].value
    return record


def run_one(config: CampaignConfig, run: int, jit: bool = False) -> dict:
    """One Monte-Carlo run: new noise, every method on the same data.

    The model file decides which methods run and on which data:

    - ``stage_data(data) -> (stage1, stage2)`` splits a simulated record (paper Table 5);
      otherwise both stages use all of it;
    - ``SWEEP_SETTINGS`` are the stage-1 settings (their seed is replaced by the run's);
    - ``BENCHMARK1_STARTS`` enables Benchmark 1 (random start, same box);
    - ``change_of_variables()`` enables Benchmark 2 (Haupt/Kasdin);
    - ``SINGLE_STAGE_START`` enables the single-stage NLP from that start.

    Parameters
    ----------
    config : CampaignConfig
    run : int
    jit : bool
        Compile the stage-2 sums for every N (default: automatically from N = 2000, see
        :class:`casest.SolverSettings`).

    Returns
    -------
    dict
        ``{"run", "seed", "methods": {name: {theta, std, cost, success, in_bounds, seconds}}}``
        with ``cost`` the ML cost (R at its optimum) on the stage-2 data; the
        ``reference`` method is the multi-start solve.
    """
    from ..backend.ipopt import SolverSettings
    from ..two_stage.sweep import SweepSettings
    from ..problem.problem import Problem

    hooks = model_file_hooks(_module(config.model))
    hooks.require("simulate", "truth", purpose="a campaign")
    model = _model(config.model)
    seed = config.first_seed + run
    data = hooks.simulate(seed)
    stage1, stage2 = hooks.stage_data(data) if hooks.stage_data is not None else (None, data)
    sweep_settings = hooks.sweep_settings
    if sweep_settings is not None:
        sweep_settings = type(sweep_settings)(**{**sweep_settings.__dict__, "seed": seed, "threads": 1})
    else:
        sweep_settings = SweepSettings(threads=1)
    # workers are processes: one thread each; jit=False leaves the automatic choice
    solver = SolverSettings(jit=True if jit else None, threads=1)
    from ..problem.noise import KnownNoise

    problem = Problem(model, stage2, stage1_data=stage1, noise=KnownNoise(config.noise) if config.noise else None,
                      fixed=config.fixed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        t = _time.perf_counter()
        est = estimate(problem, covariance=config.covariance, dof_correction=config.dof_correction,
                       sweep_settings=sweep_settings, solver_settings=solver)
        methods = {"proposed": _method_record(problem, est, _time.perf_counter() - t)}
        methods["proposed"]["verdict"] = est.landscape.verdict if est.landscape else None
        if not (config.noise or config.fixed):  # the benchmarks estimate the model file's own problem
            methods.update(_benchmarks(config, hooks, problem, stage2, seed, solver))
    return {"run": run, "seed": seed, "methods": methods}


def _benchmarks(config: CampaignConfig, hooks, problem, stage2, seed: int, solver) -> dict:
    """The methods the model file enables beside the proposed one, and the multi-start reference."""
    from .baselines import draw_start, haupt_kasdin, multistart, random_start

    model, methods, start = problem.declared_model, {}, None
    if hooks.benchmark1_starts is not None:
        start = draw_start(model, hooks.benchmark1_starts, np.random.default_rng([seed, 1]))
        t = _time.perf_counter()
        est = random_start(problem, start=start, covariance=config.covariance, solver_settings=solver,
                           dof_correction=config.dof_correction)
        methods["benchmark1"] = _method_record(problem, est, _time.perf_counter() - t)
        methods["benchmark1"]["start"] = [float(v) for v in start]
    if hooks.change_of_variables is not None and start is not None:
        t = _time.perf_counter()
        est = haupt_kasdin(model, stage2, hooks.change_of_variables(), start)
        methods["benchmark2"] = _method_record(problem, est, _time.perf_counter() - t)
    if hooks.single_stage_start is not None:
        t = _time.perf_counter()
        est = estimate(problem, start=hooks.single_stage_start, mode="full", covariance=config.covariance,
                       dof_correction=config.dof_correction, solver_settings=solver)
        methods["single_stage"] = _method_record(problem, est, _time.perf_counter() - t)
    t = _time.perf_counter()
    # the reference solves the stage-2 data alone (its starts' xi1 from those data too)
    best, _ = multistart(problem.with_data(stage2), n_starts=config.reference_starts, seed=seed, solver_settings=solver)
    methods["reference"] = {
        "theta": [float(v) for v in best.theta],
        "std": [None] * model.n_parameters,
        "cost": float(problem.profile_cost(best.theta)),
        "success": bool(best.success),
        "in_bounds": True,
        "seconds": _time.perf_counter() - t,
    }
    return methods


class _CampaignProgress:
    """The runs done as they finish: to a callable ``(done, total, seconds)``, or as a line on
    standard error at most every ``every`` seconds (where tqdm is not installed)."""

    def __init__(self, total: int, initial: int, report, every: float = 5.0):
        self.total, self.initial, self.done, self.report, self.every = total, initial, initial, report, every
        self.t0 = self.last = _time.perf_counter()

    def update(self, n: int = 1) -> None:
        self.done += n
        now = _time.perf_counter()
        if callable(self.report):
            self.report(self.done, self.total, now - self.t0)
        elif now - self.last >= self.every or (self.done == self.total and self.every < float("inf")):
            self.last = now
            left = (now - self.t0) / max(self.done - self.initial, 1) * (self.total - self.done)
            print(f"casest campaign: {self.done}/{self.total} runs, {now - self.t0:.0f} s, about {left:.0f} s left",
                  file=_sys.stderr, flush=True)

    def close(self) -> None:
        pass


def _progress(total: int, initial: int, progress):
    """A tqdm bar (``progress`` True, tqdm installed), lines on standard error (True, no tqdm), the
    callable's reports, or nothing (False)."""
    if progress is True:
        try:
            from tqdm import tqdm

            return tqdm(total=total, initial=initial, unit="run", smoothing=0.05)
        except ImportError:  # tqdm is optional (extra "parallel")
            return _CampaignProgress(total, initial, None)
    if callable(progress):
        return _CampaignProgress(total, initial, progress)
    return _CampaignProgress(total, initial, None, every=float("inf"))


def run_campaign(
    config: CampaignConfig,
    runs: int,
    out: str,
    workers: int = 1,
    scheduler: str | None = None,
    progress=True,
    jit: bool = False,
) -> dict:
    """Run (or resume) a campaign and write ``config.json``, ``runs.jsonl``, ``summary.json``, ``runs.csv``.

    Parameters
    ----------
    config : CampaignConfig
    runs : int
        Total number of runs wanted (runs already in the journal are not redone).
    out : str
        Output folder.
    workers : int
        Processes for a local pool (1: in this process).
    scheduler : str, optional
        Address of a Dask distributed scheduler; runs are submitted there instead.
    progress : bool or callable
        True: a tqdm bar (lines on standard error every 5 s where tqdm is not installed); a
        callable receives ``(runs done, runs wanted, seconds)`` as each run finishes; False:
        silent.
    jit : bool
        Compile the stage-2 sums in each worker for every N (default: automatically from
        N = 2000, see :class:`casest.SolverSettings`); it does not change the
        configuration, so a campaign may be resumed with or without it.

    Returns
    -------
    dict
        The summary (also in ``summary.json``).

    Raises
    ------
    CampaignError
        ``out`` holds a campaign with another configuration or a corrupt one, another
        campaign holds its lock, or ``runs``/``workers``/the first seed are invalid.
    """
    runs = whole_number(runs, "the number of runs must be a positive integer", error=CampaignError)
    workers = whole_number(workers, "the number of workers must be a positive integer", error=CampaignError)
    if config.first_seed < 0:
        raise CampaignError(f"the first seed must be >= 0 (NumPy seeds are non-negative), got {config.first_seed}")
    if not config.model_digest:
        config = CampaignConfig(**{**config.to_dict(), "model_digest": model_digest(config.model)})
    # never a user's own folder; a running campaign's temporary files (.tmp_*) do not make it foreign,
    # so a second campaign on its folder is told that the first is running (by the lock)
    own_folder(out, "config.json", CampaignError, ignored=(".lock",), ignored_prefixes=(".tmp_",))
    with _campaign_lock(out):
        _remove_temporary_copies(out)  # left by a campaign killed while writing (kill -9)
        return _run_locked(config, runs, out, workers, scheduler, progress, jit)


def _remove_temporary_copies(out: str) -> None:
    """Remove the ``.tmp_*`` files of atomic writes that a killed campaign left (under the lock, so
    no running campaign is writing them)."""
    for name in _os.listdir(out):
        if name.startswith(".tmp_"):
            with suppress(OSError):
                _os.remove(_os.path.join(out, name))


def model_digest(path: str) -> str:
    """SHA-256 of a model file's text (a campaign's identity is the model, not where it lies)."""
    import hashlib

    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()



@contextmanager
def _campaign_lock(out: str):
    """An exclusive lock on the output folder, so that two campaigns never compute the same runs."""
    import fcntl

    path = _os.path.join(out, ".lock")
    fh = open(path, "a+", encoding="utf-8")
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.seek(0)
        holder = fh.read().strip() or "unknown"
        fh.close()
        raise CampaignError(
            f"another campaign is running on {out!r} (process {holder}); wait for it to finish (a re-run then "
            "resumes where it stopped) or use another output folder"
        ) from None
    fh.seek(0)
    previous = fh.read().strip()
    if previous.isdigit() and int(previous) != _os.getpid() and not process_alive(int(previous)):
        warnings.warn(f"the campaign in {out!r} was locked by process {previous}, which no longer exists (killed?); "
                      "taking the lock over and resuming", stacklevel=3)
    try:
        fh.seek(0)
        fh.truncate()
        fh.write(str(_os.getpid()))
        fh.flush()
        yield
    finally:
        fh.seek(0)
        fh.truncate()  # a clean end leaves no owner behind
        fh.flush()
        fcntl.flock(fh, fcntl.LOCK_UN)
        fh.close()


def _run_locked(config, runs, out, workers, scheduler, progress, jit) -> dict:
    _claim_configuration(out, config)
    journal = Journal(_os.path.join(out, "runs.jsonl"))
    todo = [r for r in range(runs) if r not in journal.records]
    bar = _progress(runs, runs - len(todo), progress)
    try:
        _execute_runs(config, todo, journal, bar, workers, scheduler, jit)
    finally:
        bar.close()
    records = [journal.records[r] for r in sorted(journal.records) if r < runs]
    summary = summarize(config, records)
    atomic_write_text(_os.path.join(out, "summary.json"), _json.dumps(summary, indent=1) + "\n")
    atomic_write_text(_os.path.join(out, "runs.csv"), runs_csv(config, records))
    return summary


def _claim_configuration(out: str, config: CampaignConfig) -> None:
    """Write the campaign's configuration to ``out/config.json``, or check that the one there
    is the same campaign (the model by its content, so another install resumes it); a
    difference names each key with both values."""
    cfg_path = _os.path.join(out, "config.json")
    cfg = config.to_dict()
    if not _os.path.exists(cfg_path):
        atomic_write_text(cfg_path, _json.dumps(cfg, indent=1) + "\n")
        return
    try:
        with open(cfg_path, encoding="utf-8") as fh:
            old = _json.load(fh)
    except (ValueError, UnicodeDecodeError) as err:
        raise CampaignError(
            f"{cfg_path} is not a valid campaign configuration ({err}); restore it, or delete the folder to "
            "start the campaign afresh"
        ) from None
    if not isinstance(old, dict) or "model" not in old or not set(old) <= set(cfg):
        raise CampaignError(
            f"{cfg_path} is not a casest campaign configuration (keys {sorted(old) if isinstance(old, dict) else type(old).__name__}, "
            f"expected {sorted(cfg)}); use another output folder"
        )
    old = {**CampaignConfig(model=old["model"]).to_dict(), **old}  # keys added since it was written
    # the same model file content elsewhere (another install, a moved checkout) resumes
    same_model = bool(old["model_digest"]) and old["model_digest"] == cfg["model_digest"]
    differ = {k: (old[k], cfg[k]) for k in cfg if old[k] != cfg[k] and not (k == "model" and same_model)
              and not (k == "model_digest" and not old[k])}
    if differ:
        what = "; ".join(f"{k}: {a!r} in the folder, {b!r} now" for k, (a, b) in differ.items())
        raise CampaignError(f"{out} holds a campaign with another configuration ({what}); use another --out "
                            "or the same settings to resume it")
    if old != cfg:  # the same campaign from another place: record where its model is now
        atomic_write_text(cfg_path, _json.dumps(cfg, indent=1) + "\n")


def _scheduler_client(Client, address: str):
    """A Dask client of ``address``, or a CampaignError that names the address and the fix."""
    try:
        return Client(address, timeout="20s")
    except (ValueError, OSError, TimeoutError) as err:
        raise CampaignError(f"cannot reach the Dask scheduler {address!r} ({type(err).__name__}: {err}); give the "
                            "address a running scheduler prints, as tcp://HOST:PORT (start one with `dask scheduler` "
                            "and workers with `dask worker tcp://HOST:PORT`), or leave --scheduler out") from None


def _execute_runs(config, todo, journal, bar, workers, scheduler, jit) -> None:
    """Run the runs ``todo`` on a Dask scheduler, a pool of ``workers`` processes or here,
    appending each record to ``journal`` as it arrives."""
    if scheduler:
        try:
            from distributed import Client
            from distributed import as_completed as dask_completed
        except ImportError:
            raise MissingExtraError("--scheduler needs dask.distributed, which is not installed: pip install "
                                    "'casest[parallel]'") from None

        with _scheduler_client(Client, scheduler) as client:
            futures = [client.submit(run_one, config, r, jit, pure=False) for r in todo]
            for fut in dask_completed(futures):
                journal.append(fut.result())
                bar.update(1)
    elif workers > 1 and todo:
        # spawned workers hold none of this process's files (the campaign lock among them) and end
        # with it, so a campaign killed with kill -9 leaves no worker behind holding the lock
        context = _mp.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_end_with_parent,
                                 initargs=(_os.getpid(),)) as pool:
            futures = [pool.submit(run_one, config, r, jit) for r in todo]
            for fut in as_completed(futures):
                journal.append(fut.result())
                bar.update(1)
    else:
        for r in todo:
            journal.append(run_one(config, r, jit))
            bar.update(1)


def _end_with_parent(parent: int) -> None:
    """A worker's initializer: ask the kernel to end it when its parent dies (Linux), and watch
    the parent elsewhere, so that no worker outlives a killed campaign."""
    import signal
    import threading

    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # not Linux: the watcher below does it
        pass

    def watch():
        while True:
            if _os.getppid() != parent:
                _os._exit(1)
            _time.sleep(1.0)

    if _os.getppid() != parent:
        _os._exit(1)
    threading.Thread(target=watch, daemon=True).start()
