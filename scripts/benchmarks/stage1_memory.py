#!/usr/bin/env python3
"""Stage 1's process memory against N on the Pitot model: peak RSS above the record's own.

    python3 scripts/benchmarks/stage1_memory.py [--n 100000 200000 1000000] [--candidates 500]

Each N runs in two fresh processes: the first simulates the record (longer records repeat the
flight with fresh noise) and saves its arrays; the second imports casest and runs a small sweep
(the imports and builds a sweep makes), reads its RSS (``base``), loads the record (the
``Dataset``), resets the peak (Linux ``/proc/self/clear_refs``), runs ``casest.sweep`` with
``--candidates`` candidates and reads the peak RSS (``VmHWM``). Prints the record's size, the
peak above ``base`` (record and sweep together), that over the record's size, and the sweep's
peak above the RSS with the record loaded.
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
from casest.state import compiled_passes  # noqa: F401  (the imports a sweep makes, before the base)
module = casest.load_model_file(os.path.join(sys.argv[3], "..", "..", "models", "pitot5hole.py"))
model = module.model()
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


def measure(n: int, candidates: int, here: str) -> dict:
    """The record's MiB and the measuring process's base and peak RSS (MiB) for N = ``n``."""
    with tempfile.TemporaryDirectory(prefix="casest_stage1_memory_") as folder:
        path = os.path.join(folder, "record.npz")
        subprocess.run([sys.executable, "-c", MAKE, str(n), path, here], check=True, capture_output=True)
        out = subprocess.run([sys.executable, "-c", MEASURE, str(candidates), path, here], capture_output=True,
                             text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def table(ns, candidates: int, here: str, say=print) -> None:
    """The memory table for the record lengths ``ns``, each measured in fresh processes."""
    say("| N | record MiB | peak above the process before the record MiB | / record | "
        "sweep's peak above the loaded record MiB |")
    say("|---|---|---|---|---|")
    for n in ns:
        r = measure(n, candidates, here)
        above = r["peak"] - r["base"]
        say(f"| {n} | {r['record']:.1f} | {above:.0f} | {above / r['record']:.2f} | {r['peak'] - r['loaded']:.0f} |")


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
