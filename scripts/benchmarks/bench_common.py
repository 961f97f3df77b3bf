"""What the parts of scripts/benchmarks/bench.py share: the report lines, the empty compile
cache, the Pitot record of any length."""

from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.join(HERE, "..", "..")
LINES: list = []
READING = "## Reading the figures"

def cold_state() -> None:
    """As a fresh process with an empty compile cache: casest's in-process caches cleared, the
    compile cache pointed at a new empty folder (removed at exit)."""
    import atexit
    import shutil
    import tempfile

    from casest._casadi.memory import clear_memory_caches

    folder = tempfile.mkdtemp(prefix="casest_bench_cache_")
    atexit.register(shutil.rmtree, folder, True)
    os.environ["CASEST_CACHE_DIR"] = folder
    clear_memory_caches()


def say(text: str = "") -> None:
    print(text, flush=True)
    LINES.append(text)


def pitot_data(n: int, seed: int = 0):
    """A Pitot record of n samples: the simulated flight, repeated with fresh noise if longer."""
    module = casest.load_model_file(os.path.join(REPO, "models", "pitot5hole.py"))
    model = module.model()
    base = module.simulate(seed)
    if n <= base.n_samples:
        return module, model, base.subset(slice(0, n))
    parts, k = [], 0
    while sum(p.n_samples for p in parts) < n:
        parts.append(module.simulate(seed + k))
        k += 1
    signals = np.vstack([p.signals for p in parts])[:n]
    outputs = np.vstack([p.outputs for p in parts])[:n]
    return module, model, casest.Dataset.from_arrays(model, signals, outputs)


# ----------------------------------------------------------------------------- stage 1
