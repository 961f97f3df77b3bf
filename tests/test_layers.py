"""The package's imports go one way, checked by import-linter's layers contract (pyproject.toml)."""

import os
import re
import shutil
import subprocess
import sys

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LINT = shutil.which("lint-imports") or os.path.join(os.path.dirname(sys.executable), "lint-imports")

pytestmark = pytest.mark.skipif(not os.path.exists(LINT), reason="import-linter is not installed (extra 'test')")


def _lint(config: str, cwd: str, extra_path: str = ""):
    env = dict(os.environ, PYTHONPATH=extra_path + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([LINT, "--config", config, "--no-cache"], cwd=cwd, capture_output=True, text=True,
                          timeout=300, env=env)


def test_layers_contract_is_kept():
    """All three contracts: the layers, stage 2 (two_stage.solve) free of stage 1 (two_stage.sweep), and
    filter error free of the two-stage estimator."""
    proc = _lint(os.path.join(REPO, "pyproject.toml"), REPO)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "3 kept, 0 broken" in proc.stdout


@pytest.mark.parametrize("module, injected, broken", [
    ("models/static.py", "from ..two_stage import pipeline  # a lower layer importing an upper one",
     "casest_copy.models.static -> casest_copy.two_stage.pipeline"),
    ("design/experiment.py", "from ..two_stage import sweep  # a package importing its sibling",
     "casest_copy.design.experiment -> casest_copy.two_stage.sweep"),
    ("two_stage/solve/solve.py", "from ..sweep import evaluators  # stage 2 reaching into stage 1",
     "casest_copy.two_stage.solve.solve -> casest_copy.two_stage.sweep.evaluators"),
    ("filter_error/estimator.py", "from ..two_stage import sweep  # filter error reaching into two-stage",
     "casest_copy.filter_error.estimator -> casest_copy.two_stage.sweep"),
    ("filter_error/estimator.py", "from ..recursive import least_squares  # one family importing another",
     "casest_copy.filter_error.estimator -> casest_copy.recursive"),
    ("recursive/least_squares.py", "from ..two_stage import sweep  # a recursive estimator reaching into stage 1",
     "casest_copy.recursive.least_squares -> casest_copy.two_stage.sweep"),
    ("filters/kalman.py", "from ..export import filter_c  # a filter importing its C export",
     "casest_copy.filters.kalman -> casest_copy.export.filter_c"),
    ("filters/kalman.py", "from ..estimation import verdict  # the filters beside the shared machinery",
     "casest_copy.filters.kalman -> casest_copy.estimation.verdict"),
])
def test_layers_contract_catches_an_upward_import(tmp_path, module, injected, broken):
    """A copy of the package (under another name) with one import against the layers breaks the contract."""
    copy = tmp_path / "casest_copy"
    shutil.copytree(os.path.join(REPO, "casest"), copy, ignore=shutil.ignore_patterns("__pycache__"))
    target = copy / module
    target.write_text(target.read_text() + f"\n\ndef _upward():\n    {injected}\n")
    config = open(os.path.join(REPO, "pyproject.toml")).read()
    section = config[config.index("[tool.importlinter]"):]
    (tmp_path / "pyproject.toml").write_text(re.sub(r"\bcasest\b", "casest_copy", section))
    proc = _lint(str(tmp_path / "pyproject.toml"), str(tmp_path), str(tmp_path))
    assert proc.returncode != 0, proc.stdout
    assert broken in " ".join(proc.stdout.split())  # lint-imports wraps long lines


def test_no_private_names_imported_across_modules():
    """Inside the package, a module imports only public names of another (no ``from .x import _y``)."""
    import ast
    import glob

    offenders = []
    for path in glob.glob(os.path.join(REPO, "casest", "**", "*.py"), recursive=True):
        tree = ast.parse(open(path, encoding="utf-8").read())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level >= 1:
                offenders += [f"{os.path.relpath(path, REPO)}: {alias.name}" for alias in node.names
                              if alias.name.startswith("_") and not alias.name.startswith("__")]
    assert not offenders, offenders


def test_scripts_import_no_private_names():
    """The scripts use casest (and each other) through public names only: what a script needs is API."""
    import ast
    import glob

    offenders = []
    for path in glob.glob(os.path.join(REPO, "scripts", "**", "*.py"), recursive=True):
        tree = ast.parse(open(path, encoding="utf-8").read())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                offenders += [f"{os.path.relpath(path, REPO)}: {alias.name}" for alias in node.names
                              if alias.name.startswith("_") and not alias.name.startswith("__")]
    assert not offenders, offenders
