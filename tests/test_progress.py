"""An estimate says what it is doing: its stages in order, with time and peak memory.

Truth: the order of the pipeline's stages (separate, stage 1, stage 2, covariance, done) and
the clock (times non-decreasing); the command line's stage lines on standard error.
"""

import subprocess
import sys

import pytest

import casest
from casest.two_stage.progress import ProgressEvent


def test_a_callback_receives_every_stage_in_order():
    m = casest.load_model_file("scalar2")
    events = []
    est = casest.estimate(m.model(), m.simulate(seed=0), progress=events.append)
    assert est.success
    stages = [e.stage for e in events]
    # each stage once, in order; stage 2 then reports each of its solves as it starts
    assert [s for k, s in enumerate(stages) if k == 0 or s != stages[k - 1]] == \
        ["separate", "stage 1", "stage 2", "covariance", "done"]
    assert any(e.stage == "stage 2" and e.detail.startswith("solve 1 (") for e in events)
    assert all(isinstance(e, ProgressEvent) for e in events)
    assert all(a.seconds <= b.seconds for a, b in zip(events, events[1:])) and events[-1].peak_memory_mib > 0
    assert "3 start(s)" in events[2].detail or "start(s)" in events[2].detail


def test_progress_is_silent_by_default_and_refuses_nonsense(capsys):
    m = casest.load_model_file("scalar1")
    casest.estimate(m.model(), m.simulate(seed=0))
    assert "casest " not in capsys.readouterr().err
    with pytest.raises(casest.OptionError, match="progress must be True"):
        casest.estimate(m.model(), m.simulate(seed=0), progress="loud")


def test_the_command_line_prints_the_stages_on_standard_error():
    out = subprocess.run([sys.executable, "-m", "casest", "solve", "scalar1", "--quick"], capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "stage 1:" in out.stderr and "peak memory" in out.stderr and "stage 1:" not in out.stdout
    quiet = subprocess.run([sys.executable, "-m", "casest", "solve", "scalar1", "--quick", "--quiet"],
                           capture_output=True, text=True, timeout=300)
    assert "stage 1:" not in quiet.stderr
