"""Stage 1 on a dask.distributed cluster equals the local sweep, candidate by candidate.

Truth: the local sweep of the same model, data and settings in this process (the same code
on the same numbers); a LocalCluster with two worker processes, tasks of 100 candidates.
"""

from dataclasses import replace

import numpy as np
import pytest

import casest

distributed = pytest.importorskip("distributed")


def test_the_cluster_sweep_equals_the_local_sweep():
    module = casest.load_model_file("pitot5hole")
    model = module.model()
    full = module.simulate(0)
    data = full.subset(np.arange(0, full.n_samples, max(1, full.n_samples // 2000)))
    settings = casest.SweepSettings(design="random", n_candidates=600, seed=3)
    local = casest.sweep(model, data, settings=settings)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=None) as cluster:
        remote = casest.sweep(model, data, settings=replace(settings, scheduler=cluster.scheduler_address,
                                                               task_size=100))
    np.testing.assert_array_equal(remote.candidates, local.candidates)
    np.testing.assert_array_equal(remote.R, local.R)
    np.testing.assert_array_equal(remote.xi1, local.xi1)
    assert remote.best_index == local.best_index and remote.verdict == local.verdict


def test_a_bad_task_size_is_refused():
    with pytest.raises(casest.OptionError, match="task_size"):
        casest.SweepSettings(task_size=0)
