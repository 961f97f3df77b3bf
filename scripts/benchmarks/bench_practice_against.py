#!/usr/bin/env python3
"""CPU time of the practice (innovation) filter error on the bundled turbulent case against another
checkout of casest, interleaved in fresh processes.

    git worktree add /tmp/casest_baseline 1500515
    python3 scripts/benchmarks/bench_practice_against.py --baseline /tmp/casest_baseline [--repeats 7]

Contenders: the baseline as a user runs it, the baseline with NumPy's BLAS on one thread
(``OPENBLAS_NUM_THREADS=1``, its best setting on small matrices), and this checkout. Each repeat
runs every contender in a fresh process with an empty compile cache, the order reversed at every
repeat: a first estimate (cold) and two more (warm: the smaller). The estimate is
``models/turbulent_longitudinal.py`` seed 1 from the model file's ``START``,
``formulation="innovation"``, Fisher std, as ``bench_practice_filter_error.py`` runs it. Printed:
rounds, steps, median (range) CPU seconds of the process (all threads), the per-repeat ratio to the
baseline, and the largest difference of this checkout's estimate from the baseline's in the
baseline's std.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))


def child(root: str) -> dict:
    sys.path.insert(0, root)
    import casest

    mf = casest.load_model_file(os.path.join(root, "models", "turbulent_longitudinal.py"))
    model, data = mf.model(), mf.simulate(1)
    out = {}
    for label in ("cold", "warm", "warm2"):
        t0 = time.process_time()
        fe = casest.filter_error_estimate(model, data, mf.TURBULENCE_START, start=mf.START, formulation="innovation",
                                          covariance="fisher")
        out[label] = time.process_time() - t0
    out.update(theta=fe.theta.tolist(), std=fe.std.tolist(), rounds=fe.n_rounds, steps=fe.n_iterations)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--baseline", help="the other checkout's root folder")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child)))
        return 0
    contenders = {"baseline": (args.baseline, {}), "baseline, one BLAS thread": (args.baseline,
                                                                                  {"OPENBLAS_NUM_THREADS": "1"}),
                  "this checkout": (ROOT, {})}
    runs = {k: [] for k in contenders}
    print(f"{time.strftime('%Y-%m-%d %H:%M')}, load average before {os.getloadavg()[0]:.2f}")
    for rep in range(args.repeats):
        for name in (list(contenders) if rep % 2 == 0 else list(contenders)[::-1]):
            root, extra = contenders[name]
            env = dict(os.environ, CASEST_CACHE_DIR=tempfile.mkdtemp(prefix="casest_bench_"), **extra)
            out = subprocess.run([sys.executable, os.path.abspath(__file__), "--child", os.path.abspath(root)],
                                 capture_output=True, text=True, env=env, cwd=tempfile.gettempdir(), check=True)
            runs[name].append(json.loads(out.stdout.strip().splitlines()[-1]))
    print(f"load average after {os.getloadavg()[0]:.2f}")
    base = runs["baseline"]
    for name, rows in runs.items():
        warm = np.array([min(r["warm"], r["warm2"]) for r in rows])
        cold = np.array([r["cold"] for r in rows])
        ratio_w = warm / np.array([min(b["warm"], b["warm2"]) for b in base])
        ratio_c = cold / np.array([b["cold"] for b in base])
        print(f"{name}: {rows[0]['rounds']} rounds, {rows[0]['steps']} steps; warm CPU {np.median(warm):.2f} "
              f"({warm.min():.2f}-{warm.max():.2f}) s, cold {np.median(cold):.2f} ({cold.min():.2f}-{cold.max():.2f}) s; "
              f"to the baseline: warm {np.median(ratio_w):.3f} ({ratio_w.min():.3f}-{ratio_w.max():.3f}), cold "
              f"{np.median(ratio_c):.3f} ({ratio_c.min():.3f}-{ratio_c.max():.3f})")
    now, then = runs["this checkout"][0], base[0]
    moved = np.abs(np.array(now["theta"]) - np.array(then["theta"])) / np.array(then["std"])
    print(f"largest difference of this checkout's estimate from the baseline's: {np.nanmax(moved):.2g} std")
    return 0


if __name__ == "__main__":
    sys.exit(main())
