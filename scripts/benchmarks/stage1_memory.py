#!/usr/bin/env python3
"""Stage 1's process memory against N on the Pitot model: peak RSS above the record's own.

    python3 scripts/benchmarks/stage1_memory.py [--n 100000 200000] [--candidates 500]

Each N runs in a fresh process: the record is simulated (longer records repeat the flight with
fresh noise), the process's peak RSS is read, then ``casest.sweep`` runs with ``--candidates``
candidates and the peak is read again. Prints the record's size, the growth of the peak during
the sweep, and that growth per sample (what a longer record adds).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = """
import json, resource, sys
sys.path.insert(0, sys.argv[3])
from bench_common import pitot_data
import casest
N, K = int(sys.argv[1]), int(sys.argv[2])
module, model, data = pitot_data(N)
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
casest.sweep(model, data, settings=casest.SweepSettings(n_candidates=K))
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"record": (data.signals.nbytes + data.outputs.nbytes) / 2**20, "before": before, "after": after}))
"""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, nargs="+", default=[100000, 200000], help="record lengths")
    parser.add_argument("--candidates", type=int, default=500)
    args = parser.parse_args(argv)
    here = os.path.dirname(os.path.abspath(__file__))
    print("| N | record MiB | peak before the sweep MiB | peak after MiB | growth MiB | growth per sample B |")
    print("|---|---|---|---|---|---|")
    for n in args.n:
        out = subprocess.run([sys.executable, "-c", CHILD, str(n), str(args.candidates), here], capture_output=True,
                             text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        growth = r["after"] - r["before"]
        print(f"| {n} | {r['record']:.1f} | {r['before']:.0f} | {r['after']:.0f} | {growth:.0f} | "
              f"{growth * 2**20 / n:.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
