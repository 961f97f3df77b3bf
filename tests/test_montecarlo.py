"""Monte-Carlo harness: output schema, kill-and-resume, Dask, figures."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from casest.apps.montecarlo import CampaignConfig, Journal, run_campaign

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(REPO, "scripts", "campaigns", "monte_carlo.py")
SCALAR1 = os.path.join(REPO, "models", "scalar1.py")


def _config(**kw):
    return CampaignConfig(model=SCALAR1, reference_starts=kw.pop("reference_starts", 4), **kw)


def test_output_schema(tmp_path):
    summary = run_campaign(_config(), 4, str(tmp_path), workers=1, progress=False)
    assert set(os.listdir(tmp_path)) >= {"config.json", "runs.jsonl", "summary.json", "runs.csv"}
    assert summary == json.loads((tmp_path / "summary.json").read_text())
    assert summary["runs"] == 4 and summary["parameters"] == ["a", "b", "c"]
    assert set(summary["methods"]) == {"proposed", "benchmark1", "benchmark2", "reference"}
    prop = summary["methods"]["proposed"]
    for key in ("correct_pct", "global_minimum_pct", "converged_pct", "median_seconds", "p95_seconds",
                "coverage_2sigma_pct", "mc_std", "mean_reported_std", "verdicts"):
        assert key in prop
    rows = (tmp_path / "runs.csv").read_text().splitlines()
    assert rows[0].startswith("run,seed,method,a,b,c,std_a,std_b,std_c,cost")
    assert len(rows) == 1 + 4 * 4
    lines = (tmp_path / "runs.jsonl").read_text().splitlines()
    assert sorted(json.loads(line)["run"] for line in lines) == [0, 1, 2, 3]


def test_other_configuration_is_refused(tmp_path):
    run_campaign(_config(), 1, str(tmp_path), progress=False)
    with pytest.raises(ValueError, match="another configuration"):
        run_campaign(_config(dof_correction=True), 1, str(tmp_path), progress=False)


def test_killed_campaign_resumes_with_every_run_once(tmp_path):
    out = tmp_path / "mc"
    cmd = [sys.executable, SCRIPT, SCALAR1, "--runs", "40", "--workers", "2", "--out", str(out),
           "--reference-starts", "4", "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    journal = out / "runs.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline:
        if journal.exists() and len(journal.read_text().splitlines()) >= 5:
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    before = journal.read_text().splitlines()
    assert 5 <= len(before) < 40, "the campaign must be interrupted part-way"
    with open(journal, "a") as fh:
        fh.write('{"run": 39, "seed": 39, "meth')  # a torn line, as from a kill mid-write
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    after = journal.read_text().splitlines()
    runs = [json.loads(line)["run"] for line in after]
    assert sorted(runs) == list(range(40))
    kept = [line for line in before if line.endswith("}")]
    assert after[: len(kept)] == kept  # finished runs were kept verbatim, not redone
    assert json.loads((out / "summary.json").read_text())["runs"] == 40


def test_journal_drops_duplicates(tmp_path):
    path = tmp_path / "runs.jsonl"
    methods = '"methods": {"proposed": {"theta": [1.0], "std": [0.1], "success": true}}'  # a run record's least
    path.write_text(f'{{"run": 0, "x": 1, {methods}}}\n{{"run": 0, "x": 2, {methods}}}\n{{"run": 1, "x": 3, {methods}}}\n')
    j = Journal(str(path))
    assert sorted(j.records) == [0, 1] and j.records[0]["x"] == 1
    assert len(path.read_text().splitlines()) == 2


def test_dask_cluster_gives_the_same_runs(tmp_path):
    distributed = pytest.importorskip("distributed")
    local = run_campaign(_config(), 3, str(tmp_path / "local"), progress=False)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, host="127.0.0.1", dashboard_address=None,
                                  processes=True) as cluster:
        remote = run_campaign(_config(), 3, str(tmp_path / "dask"), scheduler=cluster.scheduler_address, progress=False)
    for method in local["methods"]:
        for key in ("correct_pct", "global_minimum_pct", "coverage_2sigma_pct", "mc_std"):
            assert local["methods"][method].get(key) == remote["methods"][method].get(key)
    a = sorted((tmp_path / "local" / "runs.jsonl").read_text().splitlines())
    b = sorted((tmp_path / "dask" / "runs.jsonl").read_text().splitlines())
    theta = lambda lines: [json.loads(x)["methods"]["proposed"]["theta"] for x in lines]  # noqa: E731
    np.testing.assert_array_equal(theta(a), theta(b))


def test_figures_are_png(tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "fig"
    proc = subprocess.run([sys.executable, SCRIPT, SCALAR1, "--runs", "3", "--workers", "1", "--out", str(out),
                           "--reference-starts", "2", "--figures", "--quiet"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    for name in ("landscape.png", "predictions.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_kill_9_of_the_campaign_alone_leaves_no_worker_holding_the_lock(tmp_path):
    """kill -9 of the parent only (not its process group): its workers end with it, so a resume
    starts at once; the dead owner's lock is taken over with a message."""
    out = tmp_path / "mc"
    cmd = [sys.executable, SCRIPT, SCALAR1, "--runs", "60", "--workers", "2", "--out", str(out),
           "--reference-starts", "4", "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    journal = out / "runs.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline and not (journal.exists() and len(journal.read_text().splitlines()) >= 3):
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    time.sleep(3.0)  # the workers notice within a second
    resumed = subprocess.run(cmd[:3] + ["--runs", "8"] + cmd[5:], capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert "no longer exists" in resumed.stderr and "taking the lock over" in resumed.stderr


def test_a_campaign_is_its_model_content_not_its_path(tmp_path):
    """The same model file elsewhere resumes the campaign; a changed model file is refused, naming what differs."""
    import shutil

    out = tmp_path / "mc"
    run_campaign(_config(), 2, str(out), progress=False)
    moved = tmp_path / "elsewhere" / "scalar1.py"
    moved.parent.mkdir()
    shutil.copy(SCALAR1, moved)
    summary = run_campaign(CampaignConfig(model=str(moved), reference_starts=4), 3, str(out), progress=False)
    assert summary["runs"] == 3
    moved.write_text(moved.read_text() + "\n# edited\n")
    with pytest.raises(ValueError, match="model_digest: '[0-9a-f]{64}' in the folder, '[0-9a-f]{64}' now"):
        run_campaign(CampaignConfig(model=str(moved), reference_starts=4), 3, str(out), progress=False)


def test_jit_folders_of_killed_processes_are_cleared(tmp_path):
    """kill -9 skips the exit clean-up of a process's JIT folder: the next process removes
    folders whose owner is gone and that are over an hour old, and leaves every other one."""
    from casest._casadi import numerics

    finished = subprocess.Popen([sys.executable, "-c", "pass"])
    finished.wait()
    dead, alive = finished.pid, os.getpid()
    names = {f"casest_jit_{dead}_old": True, f"casest_jit_{dead}_new": False,
             f"casest_jit_{alive}_old": True, "casest_jit_abcd": True, "unrelated": True}
    hours_ago = time.time() - 7200
    for name, old in names.items():
        os.mkdir(tmp_path / name)
        if old:
            os.utime(tmp_path / name, (hours_ago, hours_ago))
    numerics._remove_orphaned_jit_folders(str(tmp_path))
    assert sorted(os.listdir(tmp_path)) == sorted(set(names) - {f"casest_jit_{dead}_old"})


def test_a_folder_that_no_campaign_wrote_is_refused(tmp_path):
    """`casest mc --out DIR` adopted any existing folder and replaced the user's own summary.md,
    runs.csv and summary.json there, exit 0."""
    from casest.errors import CampaignError

    (tmp_path / "summary.md").write_text("my notes\n")
    (tmp_path / "runs.csv").write_text("mine\n")
    with pytest.raises(CampaignError, match=r"already holds files that no casest campaign wrote \(runs.csv, summary.md\)"):
        run_campaign(_config(), 1, str(tmp_path), progress=False)
    assert (tmp_path / "summary.md").read_text() == "my notes\n" and (tmp_path / "runs.csv").read_text() == "mine\n"
    assert not (tmp_path / "config.json").exists()


def test_an_unreachable_scheduler_is_a_campaign_error(tmp_path):
    """`casest mc --scheduler garbage` ended as "a bug in casest" (a bare ValueError from Dask)."""
    pytest.importorskip("distributed")
    from casest.errors import CampaignError

    with pytest.raises(CampaignError, match="cannot reach the Dask scheduler 'garbage'.*tcp://HOST:PORT"):
        run_campaign(_config(), 1, str(tmp_path / "out"), progress=False, scheduler="garbage")


def test_a_campaign_reports_each_run_to_a_callable(tmp_path):
    """progress= takes a callable: (runs done, runs wanted, seconds) as each run finishes, a
    resumed campaign counting the runs it already had."""
    calls = []
    run_campaign(_config(), 2, str(tmp_path), progress=lambda done, total, seconds: calls.append((done, total)))
    run_campaign(_config(), 3, str(tmp_path), progress=lambda done, total, seconds: calls.append((done, total)))
    assert calls == [(1, 2), (2, 2), (3, 3)]
