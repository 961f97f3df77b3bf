#!/usr/bin/env python3
"""Stage 1's process memory against N on the Pitot model: peak RSS above the record's own.

    python3 scripts/benchmarks/stage1_memory.py [--n 100000 200000 1000000] [--candidates 500]

Each N runs in fresh processes: the first simulates the record (longer records repeat the
flight with fresh noise) and saves its arrays; each of the others imports casest and loads the
model, reads its RSS (``base``), loads the record (the ``Dataset``), resets the peak (Linux
``/proc/self/clear_refs``), runs ``casest.sweep`` with ``--candidates`` candidates and reads the
peak RSS (``VmHWM``). The *first sweep* process does nothing else, so its peak holds the imports,
builds and compiled libraries the first sweep loads; the *later sweep* process runs a small
sweep (2000 samples, 8 candidates) before ``base``, so its peak is the sweep's own working
memory. Prints the record's size and, for each, the peak above ``base`` (record and sweep
together), that over the record's size, and the peak above the RSS with the record loaded.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

MAKE = """
import sys
sys.path.insert(0, sys.argv[3])
import numpy as np
from bench_common import pitot_data
_, _, data = pitot_data(int(sys.argv[1]))
np.savez(sys.argv[2], signals=data.signals, outputs=data.outputs)
"""

MEASURE = """
import json, os, sys
import numpy as np

def status(field):
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith(field)) / 1024

def reset_peak():  # Linux: VmHWM back to the current RSS
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")

import casest
module = casest.load_model_file(os.path.join(sys.argv[3], "..", "..", "models", "pitot5hole.py"))
model = module.model()
if sys.argv[4] == "later":  # the imports and builds a sweep makes, before the base
    from casest.filters import compiled_passes  # noqa: F401
    casest.sweep(model, module.simulate(0).subset(slice(0, 2000)), settings=casest.SweepSettings(n_candidates=8))
base = status("VmRSS")
with np.load(sys.argv[2]) as f:
    data = casest.Dataset.from_arrays(model, f["signals"], f["outputs"])
loaded = status("VmRSS")
reset_peak()
casest.sweep(model, data, settings=casest.SweepSettings(n_candidates=int(sys.argv[1])))
peak = status("VmHWM")
print(json.dumps({"record": (data.signals.nbytes + data.outputs.nbytes) / 2**20, "base": base, "loaded": loaded,
                  "peak": peak}))
"""


def measure(n: int, candidates: int, here: str, sweeps=("first", "later")) -> dict:
    """The record's MiB and, for each kind of sweep in ``sweeps`` ("first": a fresh process's
    first sweep; "later": after a small sweep), the measuring process's base, loaded and peak
    RSS (MiB) for N = ``n``: ``{"record": MiB, "first": {...}, "later": {...}}``."""
    result = {}
    with tempfile.TemporaryDirectory(prefix="casest_stage1_memory_") as folder:
        path = os.path.join(folder, "record.npz")
        subprocess.run([sys.executable, "-c", MAKE, str(n), path, here], check=True, capture_output=True)
        for kind in sweeps:
            out = subprocess.run([sys.executable, "-c", MEASURE, str(candidates), path, here, kind],
                                 capture_output=True, text=True, check=True)
            result[kind] = json.loads(out.stdout.strip().splitlines()[-1])
            result["record"] = result[kind]["record"]
    return result


def table(ns, candidates: int, here: str, say=print) -> None:
    """The memory table for the record lengths ``ns``, each measured in fresh processes."""
    say("| N | record MiB | sweep | peak above the process before the record MiB | / record | "
        "peak above the loaded record MiB |")
    say("|---|---|---|---|---|---|")
    for n in ns:
        r = measure(n, candidates, here)
        for kind in ("first", "later"):
            m = r[kind]
            above = m["peak"] - m["base"]
            say(f"| {n} | {r['record']:.1f} | {kind} | {above:.0f} | {above / r['record']:.2f} | "
                f"{m['peak'] - m['loaded']:.0f} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, nargs="+", default=[100000, 200000, 1000000], help="record lengths")
    parser.add_argument("--candidates", type=int, default=500)
    args = parser.parse_args(argv)
    here = os.path.dirname(os.path.abspath(__file__))
    table(args.n, args.candidates, here, lambda line: print(line, flush=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
