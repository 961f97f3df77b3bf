#!/usr/bin/env python3
"""A fixed CPU workload: the unit of the claims that have no peer.

    python3 scripts/benchmarks/reference_workload.py [--rounds 25]

A claim stated in CPU seconds does not hold from hour to hour: a machine's speed drifts, and
beside busy processes the CPU seconds of one process rise (shared cores and caches). The claims
with no peer (the AP2 worked example as a whole) are therefore stated as a ratio to this
workload, run as a process of its own interleaved with theirs: SciPy's ``least_squares`` (trf,
the exact Jacobian in NumPy, ``stage2_peers.py``) on the 24 bundled NIST StRD rows from their
certified starts, ``--rounds`` times over, BLAS on one thread. Printed: the process's CPU
seconds so far (imports and data included), as JSON.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before NumPy loads: the workload is one thread
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import glob  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, HERE)
sys.path.insert(0, REPO)

#: rounds over the NIST rows: about 14 CPU seconds on the 2-core machine of the claims page
ROUNDS = 25


def run(rounds: int = ROUNDS) -> float:
    """The workload; returns the process's CPU seconds since it began (all threads)."""
    import numpy as np

    from bench_stage2 import scipy_fit
    from casest.apps.nist import read_nist

    rows = [read_nist(path, start=start) for path in sorted(glob.glob(os.path.join(REPO, "data", "nist_strd", "*.dat")))
            for start in (1, 2)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(rounds):
            for row in rows:
                model = row.model
                start = np.clip(model.nominal, model.lower_bounds, model.upper_bounds)
                scipy_fit(model, row.data, start, "analytic", False, clock=time.process_time)
    return time.process_time()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=ROUNDS, help="rounds over the 24 NIST rows")
    args = parser.parse_args(argv)
    print(json.dumps({"cpu_seconds": run(args.rounds)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
