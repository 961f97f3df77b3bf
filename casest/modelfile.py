"""Loading model files (``models/NAME.py``) by name or path."""

from __future__ import annotations

import importlib.util
import os
import sys
from types import ModuleType

from .model import ModelError

__all__ = ["load_model_file", "bundled_models_dir", "bundled_data_dir", "bundled_model_names"]

_PACKAGE = os.path.dirname(os.path.abspath(__file__))


def _bundled(repository_folder: str, installed_folder: str) -> str:
    """A folder of the checkout (next to the package) or, installed from a wheel, inside it."""
    checkout = os.path.join(os.path.dirname(_PACKAGE), repository_folder)
    installed = os.path.join(_PACKAGE, installed_folder)
    if os.path.isfile(os.path.join(checkout, "__init__.py")):
        return checkout
    return installed


def bundled_models_dir() -> str:
    """The bundled model files: the checkout's ``models/`` or the installed ``casest/_models``."""
    return _bundled("models", "_models")


def bundled_data_dir(*parts: str) -> str:
    """The bundled reference data (``data/`` or the installed ``casest/_data``), joined with ``parts``."""
    return os.path.join(_bundled("data", "_data"), *parts)


def bundled_model_names() -> list:
    """Names of the bundled model files (``scalar1``, ``pitot5hole``, ...)."""
    folder = bundled_models_dir()
    if not os.path.isdir(folder):
        return []
    return sorted(f[:-3] for f in os.listdir(folder) if f.endswith(".py") and not f.startswith("_"))


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
        raise ModelFileError(
            f"no model file {name_or_path!r} (looked at {candidates}); bundled models: {bundled_model_names()}. "
            "Give a path to a .py file or one of those names"
        )
    if os.path.isdir(path):
        raise ModelFileError(f"{path!r} is a folder, not a model file; give the path of a .py file in it")
    module_name = "casest_model_" + os.path.splitext(os.path.basename(path))[0]
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise ModelFileError(f"{path!r} cannot be imported as a Python model file (it must end in .py)")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    try:
        spec.loader.exec_module(module)
    except SyntaxError as err:
        raise ModelFileError(f"model file {path!r} is not valid Python: {err.msg} (line {err.lineno})") from err
    if not hasattr(module, "model"):
        raise ModelFileError(f"model file {path!r} defines no model() function; add one that returns a casest.Model")
    return module


class ModelFileError(ModelError, FileNotFoundError):
    """A model file that cannot be found or loaded (the message says why and what to do)."""
