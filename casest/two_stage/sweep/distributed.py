"""Stage 1 on a ``dask.distributed`` cluster: the candidates as tasks, the evaluator built once per worker.

The model, partition, data and settings travel to the workers once (scattered to every worker
as one pickled blob, CasADi expressions inside :func:`casadi.global_pickle_context`); each
task evaluates a block of candidates with the evaluator the local sweep would build (same
compile decision, one thread per task: the cluster's workers and threads are the
parallelism), cached in the worker process under the blob's hash, so a worker compiles or
loads the compiled code once per sweep structure, not per task. Every candidate's xi1, R
and rank flag are computed by the same code on the same numbers as locally: the results
are identical, candidate by candidate.
"""

from __future__ import annotations

import hashlib
import pickle
from dataclasses import replace

import casadi as ca
import numpy as np

from ...errors import MissingExtraError
from .evaluators import evaluate_candidates

__all__ = ["evaluate_on_cluster"]

#: evaluators built in this (worker) process, by the hash of their inputs
_WORKER_EVALUATORS: dict = {}


def evaluate_on_cluster(build_evaluator, model, partition, data, settings, cands: np.ndarray, bounds: tuple
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """xi1 (M, n1), R (M, n_outputs) and the full-rank mask (M,) of all candidates, on ``settings.scheduler``.

    Parameters
    ----------
    build_evaluator : callable
        ``(model, partition, data, settings, n_eval) -> evaluator``, the local sweep's builder
        (a module-level function: it travels to the workers by reference).
    model, partition, data, settings
        As the local sweep has them.
    cands : ndarray, shape (M, n2)
    bounds : tuple
        The boxes of xi1 (``(None, None)`` without).

    Raises
    ------
    MissingExtraError
        dask.distributed is not installed.
    """
    try:
        from distributed import Client
    except ImportError as exc:
        raise MissingExtraError("SweepSettings(scheduler=...) needs dask.distributed, which is not installed: pip "
                                "install 'casest[parallel]'") from exc
    worker_settings = replace(settings, scheduler=None, threads=1 if settings.threads is None else settings.threads)
    with ca.global_pickle_context():
        blob = pickle.dumps((model, partition, data, worker_settings, len(cands)))
    key = hashlib.sha256(blob).hexdigest()
    size = int(settings.task_size)
    with Client(settings.scheduler) as client:
        [shared] = client.scatter([blob], broadcast=True)
        futures = [client.submit(_evaluate_block, build_evaluator, key, shared, cands[start:start + size], bounds,
                                 pure=False) for start in range(0, len(cands), size)]
        parts = client.gather(futures)
    return tuple(np.concatenate([p[k] for p in parts]) for k in range(3))


def _evaluate_block(build_evaluator, key: str, blob: bytes, cands: np.ndarray, bounds: tuple) -> tuple:
    """One task: the candidates of a block with this worker's evaluator (built on its first task)."""
    if key not in _WORKER_EVALUATORS:
        with ca.global_unpickle_context():
            model, partition, data, settings, n_eval = pickle.loads(blob)
        _WORKER_EVALUATORS.clear()  # one sweep structure at a time: an old evaluator holds its data
        _WORKER_EVALUATORS[key] = (build_evaluator(model, partition, data, settings, n_eval), data.outputs)
    evaluator, outputs = _WORKER_EVALUATORS[key]
    return evaluate_candidates(evaluator, outputs, cands, *bounds)
