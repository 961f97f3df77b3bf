"""What a long estimate is doing: its stages as they start, with the time so far and the peak memory.

``casest.estimate(..., progress=...)`` takes ``None`` (silent, the default in Python), ``True``
(a line per stage on standard error, the command line's default) or a callable that receives
each :class:`ProgressEvent`; stage 1's sweep shows a tqdm bar (when tqdm is installed) with the
candidates done and the time left whenever progress is on and the sweep is large (more than 5e7
candidate-samples: many candidates, or a long record).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from typing import Callable

from ..errors import OptionError

__all__ = ["ProgressEvent", "ProgressReporter", "peak_memory_mib"]


def peak_memory_mib() -> float:
    """The process's peak resident memory so far (MiB; NaN where the system does not say)."""
    try:
        import resource
    except ImportError:  # not on every system
        return float("nan")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 1024.0 if sys.platform != "darwin" else peak / 2**20  # kB on Linux, bytes on macOS


@dataclass(frozen=True)
class ProgressEvent:
    """A stage of an estimate starting.

    Attributes
    ----------
    stage : str
        ``"separate"``, ``"stage 1"``, ``"stage 2"``, ``"covariance"`` or ``"done"``.
    detail : str
        What the stage works on (candidates, starts, samples).
    seconds : float
        Wall time since the estimate started (s).
    peak_memory_mib : float
        The process's peak resident memory so far (MiB).
    """

    stage: str
    detail: str
    seconds: float
    peak_memory_mib: float

    def line(self) -> str:
        """The event as one line of text.

        Returns
        -------
        str
        """
        detail = f": {self.detail}" if self.detail else ""
        return f"casest {self.seconds:7.1f} s  {self.stage}{detail}  (peak memory {self.peak_memory_mib:.0f} MiB)"


class ProgressReporter:
    """Reports an estimate's stages as ``progress`` asks (module docstring).

    Parameters
    ----------
    progress : None, bool or callable
    """

    def __init__(self, progress: bool | Callable | None):
        if not (progress is None or isinstance(progress, bool) or callable(progress)):
            raise OptionError(f"progress must be True, False/None or a callable taking a casest ProgressEvent, got "
                              f"{type(progress).__name__}")
        self.progress = progress
        self.t0 = time.perf_counter()

    @property
    def on(self) -> bool:
        """Whether anything is reported (and stage 1 shows its bar)."""
        return bool(self.progress)

    def __call__(self, stage: str, detail: str = "") -> None:
        """Report that ``stage`` starts.

        Parameters
        ----------
        stage : str
        detail : str

        Returns
        -------
        None
        """
        if not self.progress:
            return
        event = ProgressEvent(stage, detail, time.perf_counter() - self.t0, peak_memory_mib())
        if callable(self.progress):
            self.progress(event)
        else:
            print(event.line(), file=sys.stderr, flush=True)
