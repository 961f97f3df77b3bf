"""Outputs to standard streams and open descriptors, and inputs that are not regular files
(casest.data.files: stream_descriptor, atomic_write_bytes, readable_file).

Truths: what a shell's ``>>`` promises (the earlier lines of the file stay, the output follows
them), what a descriptor opened for appending promises, and that a device or FIFO supplies no
record (``/dev/zero`` never ends, a FIFO without a writer never starts): each must be refused
at once, within a timeout far below what reading them would take.
"""

import os
import subprocess
import sys

import numpy as np
import pytest

import casest
from casest.data import files
from casest.errors import DataError, ResultFileError


@pytest.mark.parametrize("path, descriptor", [("-", 1), ("/dev/stdout", 1), ("/dev/stderr", 2), ("/dev/fd/7", 7),
                                              ("/proc/self/fd/9", 9), (f"/proc/{os.getpid()}/fd/5", 5),
                                              ("/proc/1/fd/5", None), ("out.json", None), ("/dev/fd", None)])
def test_the_descriptor_an_output_path_names(path, descriptor):
    assert files.stream_descriptor(path) == descriptor


def test_an_open_descriptor_is_appended_to_not_replaced(tmp_path):
    log = tmp_path / "log.txt"
    log.write_text("earlier line\n")
    with open(log, "a") as fh:
        files.atomic_write_text(f"/proc/self/fd/{fh.fileno()}", '{"json": 1}\n')
        files.atomic_write_bytes(f"/dev/fd/{fh.fileno()}", b"bytes\n")
    assert log.read_text() == 'earlier line\n{"json": 1}\nbytes\n'
    assert not any(p.name.startswith(".tmp_") for p in tmp_path.iterdir())


def test_the_cli_appends_its_json_to_what_the_shell_redirects(tmp_path):
    """``--json /dev/stdout >> log.txt``: the earlier lines stay, the JSON alone follows them (the
    report goes to standard error) and loads as the estimate."""
    log = tmp_path / "log.txt"
    log.write_text("earlier line\n")
    with open(log, "a") as out:
        run = subprocess.run([sys.executable, "-m", "casest", "solve", "scalar2", "--quick", "--quiet", "--json",
                              "/dev/stdout"], stdout=out, stderr=subprocess.PIPE, text=True, timeout=600,
                             cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    text = log.read_text()
    assert text.startswith("earlier line\n{")
    est = casest.Estimate.from_json(text[len("earlier line\n"):])
    assert est.success and "[[Conclusion]]" in run.stderr


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_devices_and_fifos_are_refused_before_anything_is_read(tmp_path):
    model = casest.load_model_file("scalar2").model()
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for path, kind in (("/dev/zero", "character device"), (str(fifo), "FIFO")):
        with pytest.raises(DataError, match=f"is a {kind}.*not a regular file"):
            casest.Dataset.from_csv(model, path)
    with pytest.raises(ResultFileError, match="is a FIFO"):
        casest.Estimate.from_json(str(fifo))


def test_a_file_larger_than_memory_can_take_is_refused(tmp_path, monkeypatch):
    model = casest.load_model_file("scalar2").model()
    path = tmp_path / "data.csv"
    path.write_text("eta,z\n" + "\n".join(f"{v},{v}" for v in np.linspace(0, 1, 2000)) + "\n")
    monkeypatch.setattr(files, "_available_memory", lambda: 4 * path.stat().st_size - 1)
    with pytest.raises(DataError, match=r"more than 25% of the memory available"):
        casest.Dataset.from_csv(model, str(path))
    monkeypatch.setattr(files, "_available_memory", lambda: 4 * path.stat().st_size + 1)
    assert casest.Dataset.from_csv(model, str(path)).n_samples == 2000


def test_options_read_by_their_truth_are_refused_by_name():
    """"yes" is true in Python and 12345 is no scheduler's address: each names the option instead
    of being taken as it reads. A figure named .xyz is refused before anything is drawn."""
    sp = casest.load_model_file("short_period")
    model = sp.model()
    ekf = casest.ExtendedKalmanFilter(model, sp.TRUTH, np.zeros(2), np.ones(3), np.eye(2) * 1e-4)
    with pytest.raises(casest.OptionError, match="compiled must be True, False or None, got 'yes'"):
        ekf.filter(sp.simulate(0), compiled="yes")
    with pytest.raises(casest.OptionError, match="max_iterations must be a whole number"):
        casest.ExtendedKalmanFilter(model, sp.TRUTH, np.zeros(2), np.ones(3), np.eye(2), iterated=True,
                                    max_iterations=0)
    with pytest.raises(casest.OptionError, match="scheduler must be a dask scheduler's address"):
        casest.SweepSettings(scheduler=12345)
    from casest.apps.cli import main

    assert main(["solve", "scalar2", "--quick", "--quiet", "--figure", "fig.xyz"]) == 2


def test_a_complex_signal_and_a_cutoff_too_low_are_named():
    y = np.sin(np.arange(500) * 0.01)
    with pytest.raises(DataError, match="complex"):
        casest.data.zero_phase_lowpass(y + 1j * y, 0.01, 5.0)
    with pytest.raises(DataError, match="too low for samples 0.01 s apart"):
        casest.data.zero_phase_lowpass(y, 0.01, 1e-9)


def test_a_slow_model_file_is_named_while_casest_waits(tmp_path, monkeypatch, capsys):
    """A model file that sleeps at import: casest cannot stop it, but says on standard error what it
    is waiting for (the notice after SLOW_USER_CODE_SECONDS, here lowered to 0.2 s)."""
    from casest.models import modelfile

    monkeypatch.setattr(modelfile, "SLOW_USER_CODE_SECONDS", 0.2)
    path = tmp_path / "sleepy.py"
    path.write_text("import time\ntime.sleep(0.8)\n\ndef model():\n    return None\n")
    modelfile.load_model_file(str(path))
    assert "still importing model file" in capsys.readouterr().err
