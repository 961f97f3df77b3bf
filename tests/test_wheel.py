"""The wheel, installed outside the checkout, holds everything a user needs and runs.

Builds the wheel with pip, installs it (with its dependencies, from PyPI or pip's cache)
in a fresh virtual environment in a temporary folder, and runs the console command there.
Needs network access or a warm pip cache: skip it offline with ``-m "not wheel"`` or
``CASEST_SKIP_WHEEL=1``. CI runs it.
"""

import os
import subprocess
import sys
import zipfile

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _run(argv, cwd, timeout=900):
    proc = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{argv} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc.stdout


@pytest.mark.slow
@pytest.mark.wheel
@pytest.mark.skipif(bool(os.environ.get("CASEST_SKIP_WHEEL")), reason="CASEST_SKIP_WHEEL is set")
def test_wheel_in_a_fresh_environment(tmp_path):
    dist = tmp_path / "dist"
    _run([sys.executable, "-m", "pip", "wheel", REPO, "--no-deps", "--quiet", "-w", str(dist)], cwd=tmp_path)
    (wheel,) = list(dist.glob("casest-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for needed in ("casest/apps/cli.py", "casest/apps/sim/flight.py", "casest/_models/scalar2.py",
                   "casest/_models/pitot5hole.py", "casest/_data/nist_strd/Misra1a.dat",
                   "casest/_data/separable/bod.csv"):
        assert needed in names, f"{needed} missing from the wheel"
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", str(venv)], cwd=tmp_path)
    python, casest_cmd = venv / "bin" / "python", venv / "bin" / "casest"
    _run([str(python), "-m", "pip", "install", "--quiet", str(wheel)], cwd=tmp_path)
    where = _run([str(python), "-c", "import casest; print(casest.__file__)"], cwd=tmp_path)
    assert str(venv) in where, where  # the installed package, not the checkout
    listing = _run([str(casest_cmd), "models"], cwd=tmp_path)
    assert "scalar2" in listing and "pitot5hole" in listing
    report = _run([str(casest_cmd), "solve", "scalar2"], cwd=tmp_path)
    assert "[[Conclusion]] trust it" in report
    pitot = _run([str(casest_cmd), "solve", "pitot5hole", "--quick"], cwd=tmp_path)
    assert "success            = True" in pitot
    separable = _run([str(python), "-c", "import casest; m = casest.load_model_file('separable'); print(m.solve('bod')[1])"],
                     cwd=tmp_path)
    assert abs(float(separable) - 25.99) < 0.01  # published RSS of BOD, from the bundled data
