"""CPU-bound processes beside a benchmark: the "busy machine" of the claims' checks.

    with cpu_bound_processes(2):
        ...   # measured beside two processes that each keep one core busy

Each process is a Python loop of floating-point arithmetic that never sleeps or touches the
disk; they are killed when the block ends.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time

#: a loop that keeps one core busy (floating-point work in the interpreter) until killed
_BUSY_LOOP = "x = 0.0\nwhile True:\n    x = (x + 1.0) * 0.5\n"


@contextlib.contextmanager
def cpu_bound_processes(count: int):
    """Run ``count`` CPU-bound processes for the duration of the block.

    Parameters
    ----------
    count : int
        How many (0: none, the block runs on an otherwise idle machine).

    Yields
    ------
    list of subprocess.Popen
        The processes (killed and reaped on leaving the block).
    """
    procs = [subprocess.Popen([sys.executable, "-c", _BUSY_LOOP], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL) for _ in range(count)]
    try:
        if procs:
            time.sleep(2.0)  # let them reach full speed (and the load average start to rise)
        yield procs
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()


def load_now() -> float:
    """The machine's 1-minute load average."""
    return os.getloadavg()[0]
