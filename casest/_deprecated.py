"""The old flat module paths (``casest.stage1``, ``casest.model``, ...), kept for one release.

casest's modules now live in subpackages (``casest.estimation.sweep``, ``casest.models``,
...). Importing an old path still works: a finder on ``sys.meta_path`` hands out the new
module itself (the same object, so classes and caches are shared) and warns with a
:class:`DeprecationWarning` naming the new path.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings


__all__ = ["MOVED", "install", "warn_keywords"]

#: old module (under casest) -> the module that replaces it
MOVED = {
    "numerics": "_casadi.numerics",
    "model": "models.static",
    "dynamic": "models.dynamic",
    "modelfile": "models.modelfile",
    "sums": "backend.sums",
    "noise": "problem.noise",
    "experiments": "problem.experiments",
    "separate": "estimation.separate",
    "stage1": "estimation.sweep",
    "stage2": "estimation.solve",
    "uncertainty": "estimation.uncertainty",
    "pipeline": "estimation.pipeline",
    "result": "estimation.result",
    "filters": "state.filters",
    "filter_error": "state.filter_error",
    "recursive": "state.recursive",
    "information": "design.information",
    "embed": "interop",
    "cli": "apps.cli",
    "montecarlo": "apps.montecarlo",
    "plots": "apps.plots",
    "baselines": "apps.baselines",
    "nist": "apps.nist",
    "sim": "apps.sim",
    "sim.flight": "apps.sim.flight",
    "sim.aircraft": "apps.sim.aircraft",
}


class _ExistingModule(importlib.abc.Loader):
    """Loads an old path as the new module object itself."""

    def __init__(self, module):
        self.module = module

    def create_module(self, spec):
        return self.module

    def exec_module(self, module):
        pass


class _MovedModules(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        package, _, rest = fullname.partition(".")
        if package != "casest" or rest not in MOVED:
            return None
        new = f"casest.{MOVED[rest]}"
        warnings.warn(f"{fullname} is deprecated and will be removed in the next release; import from {new}",
                      DeprecationWarning, stacklevel=2)
        module = importlib.import_module(new)
        return importlib.util.spec_from_loader(fullname, _ExistingModule(module))


def warn_keywords(function: str, given: list, instead: str) -> None:
    """Warn (DeprecationWarning) that ``function`` was called with keywords kept for one release.

    Parameters
    ----------
    function : str
        The public function, as the user calls it.
    given : list of str
        The deprecated keywords the call used (nothing is said when empty).
    instead : str
        What to write instead.
    """
    if given:
        warnings.warn(f"{function}({', '.join(f'{name}=...' for name in given)}) is deprecated and goes in the next "
                      f"release: {instead}", DeprecationWarning, stacklevel=3)


def install() -> None:
    """Put the finder of the old paths on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _MovedModules) for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedModules())
