"""Loading model files (``models/NAME.py``) by name or path."""

from __future__ import annotations

import importlib.util
import os
import sys
from types import ModuleType

__all__ = ["load_model_file", "bundled_models_dir"]


def bundled_models_dir() -> str:
    """The repository's ``models/`` folder (next to the ``casest`` package)."""
    return os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "models")


def load_model_file(name_or_path: str) -> ModuleType:
    """Import a model file.

    Parameters
    ----------
    name_or_path : str
        A path to a ``.py`` file, or a bare name looked up as ``./models/NAME.py`` and
        then in the repository's ``models/`` folder.

    Returns
    -------
    module
        It must define ``model()``; model files shipped here also define ``simulate(seed)``.
    """
    candidates = [name_or_path]
    if not name_or_path.endswith(".py"):
        candidates = [
            os.path.join("models", name_or_path + ".py"),
            os.path.join(bundled_models_dir(), name_or_path + ".py"),
        ]
    for path in candidates:
        if os.path.isfile(path):
            break
    else:
        available = sorted(f[:-3] for f in os.listdir(bundled_models_dir()) if f.endswith(".py") and not f.startswith("_")) if os.path.isdir(bundled_models_dir()) else []
        raise FileNotFoundError(
            f"no model file {name_or_path!r} (looked at {candidates}); bundled models: {available}"
        )
    module_name = "casest_model_" + os.path.splitext(os.path.basename(path))[0]
    spec = importlib.util.spec_from_file_location(module_name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    spec.loader.exec_module(module)
    if not hasattr(module, "model"):
        raise AttributeError(f"model file {path!r} defines no model() function")
    return module
