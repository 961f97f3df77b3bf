"""Output paths: every writer refuses what is not a regular file and writes a link's target.

Truths: the file system's own answer (os.stat, os.path.islink) after each write: a FIFO, a
device and a folder are left as they were (the write is refused with the path named), a
symbolic link stays a link and its target holds the new text, ``-`` goes to standard output.
"""

import json
import os
import stat
import subprocess
import sys

import numpy as np
import pytest

import casest
from casest.data.files import atomic_write_text


def test_a_fifo_is_refused_and_left_a_fifo(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(casest.OutputPathError, match=r"is a FIFO \(named pipe\), not a regular file"):
        atomic_write_text(fifo, "x")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_a_device_is_refused(tmp_path):
    with pytest.raises(casest.OutputPathError, match="is a character device"):
        atomic_write_text("/dev/null", "x")
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    link = tmp_path / "to_null"
    os.symlink("/dev/null", link)
    with pytest.raises(casest.OutputPathError, match="a link to '/dev/null'"):
        atomic_write_text(link, "x")


def test_a_folder_is_refused(tmp_path):
    with pytest.raises(casest.OutputPathError, match="is a folder"):
        atomic_write_text(tmp_path, "x")


def test_a_link_is_followed_and_stays_a_link(tmp_path):
    target = tmp_path / "real.json"
    target.write_text("old")
    link = tmp_path / "link.json"
    os.symlink(target, link)
    atomic_write_text(link, "new")
    assert os.path.islink(link) and target.read_text() == "new"


def test_an_estimate_written_through_a_link_and_to_standard_output(tmp_path):
    m = casest.load_model_file("scalar1")
    est = casest.estimate(m.model(), m.simulate(seed=0))
    target = tmp_path / "est.json"
    os.symlink(target, tmp_path / "link.json")
    est.to_json(str(tmp_path / "link.json"))
    assert os.path.islink(tmp_path / "link.json")
    np.testing.assert_array_equal(casest.Estimate.from_json(str(target)).theta, est.theta)


def test_the_command_line_writes_json_to_standard_output_with_a_dash():
    out = subprocess.run([sys.executable, "-m", "casest", "solve", "scalar1", "--quick", "--json", "-"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    start = out.stdout.index("{\n")
    assert json.loads(out.stdout[start:])["format"].startswith("casest.Estimate")
