"""Loading model files (``models/NAME.py``) by name or path."""

from __future__ import annotations

import contextlib
import importlib.util
import os
import sys
import threading
import traceback
from dataclasses import dataclass
from types import ModuleType
from typing import Callable, Mapping

from ..errors import ModelFileError


__all__ = ["load_model_file", "bundled_models_dir", "bundled_data_dir", "bundled_model_names", "ModelFileHooks",
           "model_file_hooks", "model_file_frame", "ModelFileError"]

_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # casest/


def _bundled(repository_folder: str, installed_folder: str) -> str:
    """A folder of the checkout (next to the package) or, installed from a wheel, inside it."""
    checkout = os.path.join(os.path.dirname(_PACKAGE), repository_folder)
    installed = os.path.join(_PACKAGE, installed_folder)
    if os.path.isfile(os.path.join(checkout, "__init__.py")):
        return checkout
    return installed


def bundled_models_dir() -> str:
    """The folder of the bundled model files.

    Returns
    -------
    str
        The checkout's ``models/`` or the installed ``casest/_models``.
    """
    return _bundled("models", "_models")


def bundled_data_dir(*parts: str) -> str:
    """The bundled reference data folder, joined with ``parts``.

    Parameters
    ----------
    *parts : str
        Path components below it (``"nist_strd", "Misra1a.dat"``).

    Returns
    -------
    str
        A path in the checkout's ``data/`` or the installed ``casest/_data``.
    """
    return os.path.join(_bundled("data", "_data"), *parts)


def bundled_model_names() -> list:
    """Names of the bundled model files.

    Returns
    -------
    list of str
        ``scalar1``, ``scalar2``, ``pitot5hole``, ... (sorted), each loadable by
        :func:`load_model_file`.
    """
    folder = bundled_models_dir()
    if not os.path.isdir(folder):
        return []
    return sorted(f[:-3] for f in os.listdir(folder) if f.endswith(".py") and not f.startswith("_"))


#: real paths of the model files imported by :func:`load_model_file` in this process
_LOADED_FILES: set = set()


def model_file_frame(tb) -> traceback.FrameSummary | None:
    """The innermost traceback frame that runs in a model file loaded by :func:`load_model_file`.

    An exception raised there (or in what the model file called) is the model file's to fix,
    not casest's: the command line reports it as a user error naming the file and line.

    Parameters
    ----------
    tb : traceback
        The traceback of an exception (``exc.__traceback__``).

    Returns
    -------
    traceback.FrameSummary or None
        Its ``filename``, ``lineno`` and ``name``; None when no frame is in a model file.
    """
    for frame in reversed(traceback.extract_tb(tb)):
        if os.path.realpath(frame.filename) in _LOADED_FILES:
            return frame
    return None


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
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise ModelFileError(f"a model file is named by a bundled name or a path, got {type(name_or_path).__name__}")
    name_or_path = os.fspath(name_or_path)
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
    _LOADED_FILES.add(os.path.realpath(path))
    try:
        with slow_user_code_notice(f"importing model file {path!r}"):
            spec.loader.exec_module(module)
    except SyntaxError as err:
        raise ModelFileError(f"model file {path!r} is not valid Python: {err.msg} (line {err.lineno})") from err
    except SystemExit as err:  # sys.exit() at import would end the caller silently (exit 0)
        sys.modules.pop(module_name, None)
        raise ModelFileError(f"model file {path!r} called sys.exit({err.code!r}) while it was imported; a model file "
                             "only defines model() (and its helpers): put scripts under if __name__ == '__main__':") from None
    except Exception as err:  # the file's own code failed while it was imported
        sys.modules.pop(module_name, None)
        frame = model_file_frame(err.__traceback__)
        where = f" at line {frame.lineno}" if frame is not None else ""
        raise ModelFileError(f"model file {path!r} raised {type(err).__name__}{where} while it was imported: {err}; "
                             "fix the file") from err
    if not hasattr(module, "model"):
        raise ModelFileError(f"model file {path!r} defines no model() function; add one that returns a casest.Model")
    return module



#: seconds of a model file's own code before casest says what it is waiting for
SLOW_USER_CODE_SECONDS = 10.0


@contextlib.contextmanager
def slow_user_code_notice(what: str, after: float | None = None, advice: str | None = None):
    """Say on standard error, once, when user code (or a step whose time grows with the user's
    model) runs longer than ``after`` seconds.

    A model file's top-level code and its ``model()`` are the user's: casest cannot stop a
    file that sleeps or loops, but it can say what it is waiting for instead of hanging silently.

    Parameters
    ----------
    what : str
        What is running (``"importing model file 'm.py'"``).
    after : float, optional
        Seconds before the notice (default :data:`SLOW_USER_CODE_SECONDS`).
    advice : str, optional
        What to look at (default: the model file's own code).

    Yields
    ------
    None
    """
    delay = SLOW_USER_CODE_SECONDS if after is None else float(after)

    advice = advice or ("this is the file's own code (its top level or model()); if it should be quick, look for a "
                        "loop, a sleep or a large computation there, and stop with Ctrl-C")

    def notice():
        print(f"casest: still {what} after {delay:g} s: {advice}", file=sys.stderr, flush=True)

    timer = threading.Timer(delay, notice)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


@dataclass(frozen=True)
class ModelFileHooks:
    """What a model file offers beside ``model()``: the protocol the tools read.

    A model file may export ``HOOKS = ModelFileHooks(...)``; otherwise the hooks are read
    from its module-level names (given in brackets). Everything but ``model`` is optional.

    Attributes
    ----------
    model : callable
        ``model() -> casest.Model`` (``model``).
    simulate : callable, optional
        ``simulate(seed) -> casest.Dataset`` with known truth (``simulate``); needed by
        ``casest solve`` without ``--data`` and by campaigns.
    truth : mapping of str to float, optional
        The parameters ``simulate`` uses (``TRUTH``); needed by campaigns.
    stage_data : callable, optional
        ``stage_data(data) -> (stage1_data, stage2_data)``, the manoeuvre windows of each
        stage (``stage_data``; paper Table 5).
    sweep_settings : SweepSettings, optional
        Stage-1 settings for this model (``SWEEP_SETTINGS``).
    benchmark1_starts : mapping, optional
        Distributions of Benchmark 1's random starts (``BENCHMARK1_STARTS``).
    single_stage_start : mapping, optional
        The single-stage baseline's start (``SINGLE_STAGE_START``).
    change_of_variables : callable, optional
        Benchmark 2's change of variables (``change_of_variables``).
    """

    model: Callable
    simulate: Callable | None = None
    truth: Mapping | None = None
    stage_data: Callable | None = None
    sweep_settings: object | None = None
    benchmark1_starts: Mapping | None = None
    single_stage_start: Mapping | None = None
    change_of_variables: Callable | None = None

    def require(self, *names: str, purpose: str) -> None:
        """Raise a :class:`ModelFileError` naming the hooks that ``purpose`` needs and that are missing.

        Parameters
        ----------
        *names : str
            Hook names.
        purpose : str
            What needs them, for the message.

        Returns
        -------
        None
        """
        missing = [n for n in names if getattr(self, n) is None]
        if missing:
            legacy = {"truth": "TRUTH", "sweep_settings": "SWEEP_SETTINGS"}
            raise ModelFileError(
                f"the model file lacks {[legacy.get(n, n) for n in missing]}, which {purpose} needs; define "
                "them in the file (or export HOOKS = casest.ModelFileHooks(...))"
            )


#: module-level names read when a model file does not export HOOKS
_HOOK_NAMES = {
    "model": "model", "simulate": "simulate", "truth": "TRUTH", "stage_data": "stage_data",
    "sweep_settings": "SWEEP_SETTINGS", "benchmark1_starts": "BENCHMARK1_STARTS",
    "single_stage_start": "SINGLE_STAGE_START", "change_of_variables": "change_of_variables",
}


def model_file_hooks(module: ModuleType) -> ModelFileHooks:
    """The :class:`ModelFileHooks` of a loaded model file, checked.

    Parameters
    ----------
    module : module
        A model file loaded by :func:`load_model_file`.

    Returns
    -------
    ModelFileHooks
        Its ``HOOKS``, or else its module-level names (``simulate``, ``TRUTH``, ...).

    Raises
    ------
    ModelFileError
        A hook of the wrong kind (the message names it).
    """
    hooks = getattr(module, "HOOKS", None)
    if hooks is None:
        hooks = ModelFileHooks(**{field: getattr(module, name, None) for field, name in _HOOK_NAMES.items()})
    elif not isinstance(hooks, ModelFileHooks):
        raise ModelFileError(f"HOOKS in {getattr(module, '__file__', module)!r} must be a casest.ModelFileHooks")
    for field in ("model", "simulate", "stage_data", "change_of_variables"):
        value = getattr(hooks, field)
        if value is not None and not callable(value):
            raise ModelFileError(f"{_HOOK_NAMES[field]} in the model file must be a function, got {type(value).__name__}")
    for field in ("truth", "benchmark1_starts", "single_stage_start"):
        value = getattr(hooks, field)
        if value is not None and not isinstance(value, Mapping):
            raise ModelFileError(f"{_HOOK_NAMES[field]} in the model file must be a mapping name -> value")
    return hooks
