"""The streamed sweep (tasks that generate their own candidates, keep their best, and are stored
so that an interrupted sweep resumes) against the local sweep.

Truths: ``draw_candidates``' design (each task's rows equal the same rows of the whole design,
exactly); the local ``casest.sweep`` of the same design (the streamed sweep's best candidates are
its best by Tr[R], with the same xi1 and R, exactly: the same evaluator on the same numbers).
"""

import json
import os
from dataclasses import replace

import numpy as np
import pytest

import casest
from casest.two_stage.sweep.candidates import draw_candidates
from casest.two_stage.sweep.streamed import streamed_sweep, task_candidates


@pytest.fixture(scope="module")
def pitot():
    module = casest.load_model_file("pitot5hole")
    model = module.model()
    return model, module.simulate(0).subset(slice(0, 1500))


@pytest.mark.parametrize("design", ["random", "sobol", "grid"])
def test_each_tasks_rows_are_the_designs(pitot, design):
    model, _ = pitot
    part = casest.separate(model)
    settings = casest.SweepSettings(design=design, n_candidates=2500, seed=5)
    whole, _, _ = draw_candidates(model, part, settings)
    rows = [task_candidates(model, part, settings, a, min(a + 333, len(whole))) for a in range(0, len(whole), 333)]
    np.testing.assert_array_equal(np.vstack(rows), whole)


def test_the_best_candidates_are_the_local_sweeps(pitot):
    model, data = pitot
    settings = casest.SweepSettings(design="random", n_candidates=2000, seed=3, task_size=300)
    streamed = streamed_sweep(model, data, settings, keep=12)
    local = casest.sweep(model, data, settings=settings)
    order = np.argsort(local.trace_R[:2000], kind="stable")[:12]
    np.testing.assert_array_equal(streamed.indices, order)
    np.testing.assert_array_equal(streamed.candidates, local.candidates[order])
    np.testing.assert_array_equal(streamed.R, local.R[order])
    np.testing.assert_array_equal(streamed.xi1, local.xi1[order])
    assert streamed.n_evaluated == 2000 and len(streamed.task_best) == 7 and streamed.tasks_run == 7
    assert streamed.task_best.min() == streamed.ranking[0]


def test_an_interrupted_sweep_resumes_from_its_store(pitot, tmp_path):
    model, data = pitot
    settings = casest.SweepSettings(design="sobol", n_candidates=1500, seed=2, task_size=400)
    store = str(tmp_path / "sweep")
    first = streamed_sweep(model, data, settings, store=store, keep=8)
    os.remove(os.path.join(store, "task_00000001.json"))  # as if the sweep had stopped before task 1 finished
    with open(os.path.join(store, "task_00000003.json"), "w") as fh:
        fh.write("{\"start\": 12")  # a half-written file: run again
    resumed = streamed_sweep(model, data, settings, store=store, keep=8)
    assert (resumed.tasks_loaded, resumed.tasks_run) == (2, 2)
    np.testing.assert_array_equal(resumed.indices, first.indices)
    np.testing.assert_array_equal(resumed.R, first.R)
    with pytest.raises(casest.OptionError, match="another sweep"):
        streamed_sweep(model, data, replace(settings, seed=9), store=store, keep=8)
    assert json.load(open(os.path.join(store, "sweep.json")))["n_candidates"] == 1500


def test_what_it_refuses(pitot, tmp_path):
    model, data = pitot
    a_file = tmp_path / "not_a_folder"
    a_file.write_text("x")
    with pytest.raises(casest.OptionError, match="is a file"):
        streamed_sweep(model, data, casest.SweepSettings(design="random", n_candidates=10), store=str(a_file))
    with pytest.raises(casest.OptionError, match="integer seed"):
        streamed_sweep(model, data, casest.SweepSettings(seed=np.random.default_rng(1)))
    with pytest.raises(casest.OptionError, match="keep must be"):
        streamed_sweep(model, data, casest.SweepSettings(design="random"), keep=0)


def test_on_a_cluster_it_equals_the_local_streamed_sweep(pitot):
    distributed = pytest.importorskip("distributed")
    model, data = pitot
    settings = casest.SweepSettings(design="random", n_candidates=1200, seed=4, task_size=200)
    local = streamed_sweep(model, data, settings, keep=10)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=None) as cluster:
        remote = streamed_sweep(model, data, replace(settings, scheduler=cluster.scheduler_address), keep=10)
    np.testing.assert_array_equal(remote.indices, local.indices)
    np.testing.assert_array_equal(remote.R, local.R)
    np.testing.assert_array_equal(remote.task_best, local.task_best)


def test_a_store_written_by_another_process_is_resumed(pitot, tmp_path):
    """The store's key is the same in every process (the model's structure and the data's bytes,
    not a pickle): a sweep stored by a child process is loaded here."""
    import subprocess
    import sys

    model, data = pitot
    store = str(tmp_path / "sweep")
    child = (
        "import casest\n"
        "from casest.two_stage.sweep.streamed import streamed_sweep\n"
        "module = casest.load_model_file('pitot5hole')\n"
        "data = module.simulate(0).subset(slice(0, 1500))\n"
        f"streamed_sweep(module.model(), data, casest.SweepSettings(design='random', n_candidates=900, seed=1, "
        f"task_size=300), store={store!r}, keep=5)\n")
    subprocess.run([sys.executable, "-c", child], check=True, capture_output=True, timeout=300)
    os.remove(os.path.join(store, "task_00000000.json"))
    here = streamed_sweep(model, data, casest.SweepSettings(design="random", n_candidates=900, seed=1, task_size=300),
                          store=store, keep=5)
    assert (here.tasks_loaded, here.tasks_run) == (2, 1)
    fresh = streamed_sweep(model, data, casest.SweepSettings(design="random", n_candidates=900, seed=1, task_size=300),
                           keep=5)
    np.testing.assert_array_equal(here.indices, fresh.indices)
    np.testing.assert_array_equal(here.R, fresh.R)
