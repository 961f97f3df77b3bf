"""Stage 1 over more candidates than one machine holds: the design streamed in tasks, each task's
candidates generated where it runs, only its best candidates and a summary kept, and every
finished task stored so that an interrupted sweep resumes.

A task is a contiguous range of the design's candidates, which it generates from the design and
the seed alone (:func:`task_candidates`: rows ``start:stop`` of exactly the candidates
:func:`~casest.two_stage.sweep.candidates.draw_candidates` draws for the whole design). It
evaluates them with the evaluator the local sweep would build, ranks them by the sweep's
criterion and returns its ``keep`` best (candidates, xi1, R, ranking values) and a summary
(candidates evaluated, full-rank fits, best value). The driver merges the tasks' best into the
sweep's ``keep`` best as they finish, writes each task's result to ``store`` (atomically), and
on a later call loads the stored tasks instead of running them. Peak memory is one task's
candidates per worker and ``keep`` candidates per task in the driver, whatever the design's size.
"""

from __future__ import annotations

import hashlib
import math
import os
import pickle
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from ..._casadi.array_json import decode_array, encode_array
from ...data.files import atomic_write_text
from ...errors import MissingExtraError, OptionError
from .analysis import ranking_values
from .candidates import scrambled_sobol_rows
from .evaluators import evaluate_candidates
from .settings import SweepSettings
from ...options import SweepCriterion
from ...checks import whole_number

__all__ = ["StreamedSweep", "streamed_sweep", "task_candidates", "design_size"]


@dataclass
class StreamedSweep:
    """The best candidates of a streamed sweep and its per-task summary.

    Attributes
    ----------
    candidates : ndarray, shape (keep, n2)
        The best xi2 candidates, best first (physical units).
    xi1 : ndarray, shape (keep, n1)
    R : ndarray, shape (keep, n_outputs)
    ranking : ndarray, shape (keep,)
        The criterion's value (Tr[R] or the profile ML cost), ascending.
    indices : ndarray of int, shape (keep,)
        Their rows in the whole design.
    n_candidates : int
        The design's size.
    task_size : int
    task_evaluated, task_full_rank : ndarray of int, shape (n_tasks,)
        Per task: candidates evaluated, fits with A(xi2) of full rank.
    task_best : ndarray, shape (n_tasks,)
        Per task: its best ranking value (inf where no fit).
    tasks_loaded, tasks_run : int
        Tasks read from the store, tasks evaluated by this call.
    criterion : str
    """

    candidates: np.ndarray
    xi1: np.ndarray
    R: np.ndarray
    ranking: np.ndarray
    indices: np.ndarray
    n_candidates: int
    task_size: int
    task_evaluated: np.ndarray
    task_full_rank: np.ndarray
    task_best: np.ndarray
    tasks_loaded: int = 0
    tasks_run: int = 0
    criterion: SweepCriterion = "trace"
    notes: list = field(default_factory=list)

    @property
    def n_evaluated(self) -> int:
        """Candidates evaluated over all tasks."""
        return int(self.task_evaluated.sum())


def task_candidates(model, partition, settings: SweepSettings, start: int, stop: int) -> np.ndarray:
    """Rows ``start:stop`` of the candidates :func:`draw_candidates` draws for ``settings``.

    Parameters
    ----------
    model : Model or DynamicModel
    partition : Partition
    settings : SweepSettings
        ``design`` ("random", "sobol" or "grid"; "auto" resolved as the sweep does), the design's
        size ``n_candidates`` and an integer ``seed``.
    start, stop : int
        The rows.

    Returns
    -------
    ndarray, shape (stop - start, n2)
    """
    params = [model.parameters[i] for i in partition.nonlinear_index]
    n2 = len(params)
    design = _design(settings, n2)
    if design == "random":
        generator = np.random.PCG64(settings.seed)
        generator.advance(start * n2)  # Generator.random draws one 64-bit output per double, row by row
        u = np.random.Generator(generator).random((stop - start, n2))
    elif design == "sobol":
        u = scrambled_sobol_rows(n2, int(settings.seed), start, stop)
    else:
        per_dim = max(2, int(math.floor(settings.n_candidates ** (1.0 / n2) + 1e-9)))
        index = np.arange(start, stop)
        digits = np.stack(np.unravel_index(index, (per_dim,) * n2), axis=1)
        axes = []
        for p in params:
            finite = p.sampling_prior.finite_support(p.lb, p.ub)
            axes.append(np.linspace(0.0, 1.0, per_dim) if finite else (np.arange(per_dim) + 0.5) / per_dim)
        u = np.column_stack([axes[j][digits[:, j]] for j in range(n2)])
    return np.column_stack([p.sampling_prior.ppf(u[:, j], p.lb, p.ub) for j, p in enumerate(params)])


def design_size(settings: SweepSettings, n2: int) -> int:
    """The number of candidates the design has (a grid: ``per_dim ** n2``).

    Parameters
    ----------
    settings : SweepSettings
    n2 : int

    Returns
    -------
    int
    """
    if _design(settings, n2) == "grid":
        return max(2, int(math.floor(settings.n_candidates ** (1.0 / n2) + 1e-9))) ** n2
    return int(settings.n_candidates)


def _design(settings: SweepSettings, n2: int) -> str:
    design = settings.design if settings.design != "auto" else ("grid" if n2 <= 2 else "sobol")
    if design not in ("random", "sobol", "grid"):
        raise OptionError(f"a streamed sweep generates its candidates from the design: 'random', 'sobol' or 'grid', "
                          f"not {design!r}")
    return design


#: evaluators built in this (worker) process, by the hash of their inputs
_TASK_EVALUATORS: dict = {}


def _run_task(build_evaluator, key: str, blob: bytes, start: int, stop: int, bounds: tuple, keep: int) -> dict:
    """One task: generate rows ``start:stop`` of the design, evaluate them, keep the best ``keep``."""
    if key not in _TASK_EVALUATORS:
        with ca.global_unpickle_context():
            model, partition, data, settings, n_design = pickle.loads(blob)
        _TASK_EVALUATORS.clear()  # one sweep at a time: an old evaluator holds its data
        # built for the whole design (the compile decision), as the local sweep's evaluator is
        evaluator = build_evaluator(model, partition, data, settings, n_design)
        _TASK_EVALUATORS[key] = (model, partition, data, settings, evaluator)
    model, partition, data, settings, evaluator = _TASK_EVALUATORS[key]
    cands = task_candidates(model, partition, settings, start, stop)
    xi1, R, ok = evaluate_candidates(evaluator, data.outputs, cands, *bounds)
    rank = ranking_values(settings.criterion, R, ok, data.observed_counts())
    best = np.argsort(rank, kind="stable")[:keep]
    return {"start": start, "stop": stop, "candidates": cands[best], "xi1": xi1[best], "R": R[best],
            "ranking": rank[best], "indices": start + best, "evaluated": stop - start, "full_rank": int(ok.sum()),
            "best": float(rank[best[0]]) if len(best) else np.inf}


def _merge(kept: dict | None, task: dict, keep: int) -> dict:
    """The ``keep`` best of the kept candidates and a task's (ties: the lower design row first)."""
    fields = ("candidates", "xi1", "R", "ranking", "indices")
    if kept is None:
        both = {f: task[f] for f in fields}
    else:
        both = {f: np.concatenate([kept[f], task[f]]) for f in fields}
    order = np.lexsort((both["indices"], both["ranking"]))[:keep]
    return {f: both[f][order] for f in fields}


def _task_path(store: str, task: int) -> str:
    return os.path.join(store, f"task_{task:08d}.json")


def _save_task(store: str, task: int, result: dict) -> None:
    import json

    encoded = {k: (encode_array(np.asarray(v)) if isinstance(v, np.ndarray) else v) for k, v in result.items()}
    encoded["best"] = repr(float(result["best"]))
    atomic_write_text(_task_path(store, task), json.dumps(encoded))


def _load_task(store: str, task: int) -> dict | None:
    import json

    try:
        with open(_task_path(store, task), encoding="utf-8") as fh:
            raw = json.load(fh)
    except (OSError, ValueError):
        return None  # not stored, or unreadable: run it again
    out = {k: (decode_array(v, dtype=int if k == "indices" else float) if isinstance(v, dict) else v)
           for k, v in raw.items()}
    out["best"] = float(out["best"])
    return out


def _open_store(store: str, key: str, description: dict) -> None:
    """Create the store, or check that it holds this very sweep (refuse another's tasks)."""
    import json

    if os.path.exists(store) and not os.path.isdir(store):
        raise OptionError(f"the store {store!r} is a file: give a folder (created if missing)")
    os.makedirs(store, exist_ok=True)
    manifest = os.path.join(store, "sweep.json")
    if os.path.exists(manifest):
        with open(manifest, encoding="utf-8") as fh:
            stored = json.load(fh)
        if stored.get("key") != key:
            raise OptionError(f"the store {store!r} holds the tasks of another sweep (another model, data, design or "
                              "settings): give an empty folder, or the one of this sweep")
        return
    atomic_write_text(manifest, json.dumps({"key": key, **description}, indent=1) + "\n")


def streamed_sweep(model, data=None, settings: SweepSettings | None = None, store: str | None = None,
                   keep: int = 64) -> StreamedSweep:
    """Stage 1 over a design of any size, in tasks that generate their own candidates.

    Parameters
    ----------
    model : Model, DynamicModel or Problem
        As :func:`casest.sweep` takes it.
    data : Dataset, optional
        The sweep's samples (not with a Problem).
    settings : SweepSettings, optional
        ``design`` ("random", "sobol" or "grid"), ``n_candidates`` (the design's size), an integer
        ``seed``, ``task_size`` (candidates per task), ``criterion`` and ``scheduler`` (a
        ``dask.distributed`` scheduler address or ``Client``; None: the tasks run here in turn).
    store : str, optional
        A folder for the finished tasks: each is written there as it finishes, and a later call
        with the same folder loads them instead of running them again (an interrupted sweep
        resumes). The folder is tied to this sweep: another sweep's folder is refused.
    keep : int
        Best candidates kept per task and overall.

    Returns
    -------
    StreamedSweep
        The ``keep`` best candidates with their xi1, R and ranking values, and a summary per task.
        ``casest.sweep(model, data, candidates=result.candidates)`` judges them as a landscape.

    Raises
    ------
    OptionError
        A design the tasks cannot generate, a seed that is not an integer, ``keep < 1``, or a store
        that holds another sweep.
    """
    from .orchestration import sweep_inputs, candidate_evaluator, linear_parameter_bounds

    settings = settings or SweepSettings(design="random")
    if not isinstance(settings.seed, (int, np.integer)) or isinstance(settings.seed, bool):
        raise OptionError(f"a streamed sweep draws each task's candidates from an integer seed, got {settings.seed!r}")
    keep = whole_number(keep, "keep must be a positive integer")
    model, data, partition, _ = sweep_inputs(model, data, None)
    if partition.n_nonlinear == 0:
        raise OptionError(f"{model.name} has no nonlinear parameter: there is nothing to sweep")
    n2 = partition.n_nonlinear
    size, task_size = design_size(settings, n2), int(settings.task_size)
    worker_settings = replace(settings, scheduler=None, threads=1 if settings.scheduler else settings.threads)
    with ca.global_pickle_context():
        blob = pickle.dumps((model, partition, data, worker_settings, size))
    description = {"design": _design(settings, n2), "n_candidates": size, "seed": int(settings.seed),
                   "task_size": task_size, "keep": int(keep), "criterion": settings.criterion}
    bounds = linear_parameter_bounds(model, partition)
    key = _sweep_key(model, partition, data, settings, description, bounds)
    tasks = [(t, t * task_size, min(size, (t + 1) * task_size)) for t in range(-(-size // task_size))]
    merged = _Merged(len(tasks), keep, store)
    if store is not None:
        _open_store(store, key, description)
    pending = [(t, start, stop) for t, start, stop in tasks if not merged.load(t)]
    if settings.scheduler:
        _run_on_cluster(settings.scheduler, blob, key, pending, bounds, keep, merged.add)
    else:
        for t, start, stop in pending:
            merged.add(t, _run_task(candidate_evaluator, key, blob, start, stop, bounds, keep))
    kept = merged.kept
    return StreamedSweep(candidates=kept["candidates"], xi1=kept["xi1"], R=kept["R"], ranking=kept["ranking"],
                         indices=kept["indices"].astype(int), n_candidates=size, task_size=task_size,
                         task_evaluated=merged.summary[:, 0].astype(int), task_full_rank=merged.summary[:, 1].astype(int),
                         task_best=merged.summary[:, 2], tasks_loaded=merged.loaded, tasks_run=len(pending),
                         criterion=settings.criterion)


class _Merged:
    """The sweep's best candidates and per-task summary as tasks finish or load from the store."""

    def __init__(self, n_tasks: int, keep: int, store: str | None):
        self.keep, self.store = keep, store
        self.kept, self.loaded = None, 0
        self.summary = np.zeros((n_tasks, 3))

    def load(self, t: int) -> bool:
        """Merge task ``t`` from the store; False when it is not stored (or unreadable)."""
        result = _load_task(self.store, t) if self.store is not None else None
        if result is None:
            return False
        self._merge(t, result)
        self.loaded += 1
        return True

    def add(self, t: int, result: dict) -> None:
        """A task just finished: store it (atomically), then merge it."""
        if self.store is not None:
            _save_task(self.store, t, result)
        self._merge(t, result)

    def _merge(self, t: int, result: dict) -> None:
        self.kept = _merge(self.kept, result, self.keep)
        self.summary[t] = (result["evaluated"], result["full_rank"], result["best"])


def _sweep_key(model, partition, data, settings: SweepSettings, description: dict, bounds: tuple) -> str:
    """What identifies a sweep's results, the same in every process: the model's structure, the
    split, the data's bytes, the design and the settings that change a candidate's fit."""
    h = hashlib.sha256()
    for part in (model.structure_key, repr((partition.linear, partition.nonlinear)), repr(sorted(description.items())),
                 repr((settings.method, settings.condition_limit)), repr(bounds)):
        h.update(part.encode() + b"\0")
    for array in (data.signals, data.outputs, data.observed if data.observed is not None else np.zeros(0)):
        h.update(np.ascontiguousarray(array).tobytes())
    return h.hexdigest()


def _run_on_cluster(scheduler, blob: bytes, key: str, pending: list, bounds: tuple, keep: int, finished) -> None:
    """The pending tasks on a dask.distributed cluster, each handed to ``finished`` as it completes."""
    from .orchestration import candidate_evaluator

    try:
        from distributed import Client, as_completed
    except ImportError as exc:
        raise MissingExtraError("SweepSettings(scheduler=...) needs dask.distributed, which is not installed: pip "
                                "install 'casest[parallel]'") from exc
    client = scheduler if isinstance(scheduler, Client) else Client(scheduler)
    try:
        [shared] = client.scatter([blob], broadcast=True)
        futures = {client.submit(_run_task, candidate_evaluator, key, shared, start, stop, bounds, keep, pure=False): t
                   for t, start, stop in pending}
        for future in as_completed(futures):
            finished(futures[future], future.result())
            future.release()
    finally:
        if client is not scheduler:
            client.close()
