"""Cold start and scaling in N of scripts/benchmarks/bench.py (each measured in fresh processes)."""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from bench_common import HERE, cold_state, pitot_data, say

import casest  # noqa: E402


COLD_SCRIPT = """
import json, time
t0, c0 = time.perf_counter(), time.process_time()
import casest
t_import, c_import = time.perf_counter() - t0, time.process_time() - c0
from casest.models import model_file_hooks
from casest._casadi.numerics import compile_stats
out = {"import": t_import, "import_cpu": c_import}
module = casest.load_model_file("pitot5hole")
hooks = model_file_hooks(module)
data = module.simulate(0)
stage1, data = hooks.stage_data(data) if hooks.stage_data is not None else (None, data)

def run(model):
    before = dict(compile_stats())
    t, c = time.perf_counter(), time.process_time()
    est = casest.estimate(model, data, stage1_data=stage1, sweep_settings=hooks.sweep_settings)
    after = compile_stats()
    out["cpu"] = time.process_time() - c
    return time.perf_counter() - t, {k: after[k] - before.get(k, 0) for k in after}, bool(est.success)

model = module.model()
out["first"] = run(model)
out["first_cpu"] = out.pop("cpu")
out["fresh_object"] = run(module.model())
out["warm"] = run(model)
out.pop("cpu")
est = casest.estimate(model, data, stage1_data=stage1, sweep_settings=hooks.sweep_settings)
out["stage1_point"] = [float(v) for v in est.starts[0].theta0]  # the best stage-1 candidate, SciPy's start
print(json.dumps(out))
"""

# SciPy's first fit in a fresh process (its CPU seconds): least_squares (trf, the NumPy residual and Jacobian of
# scripts/benchmarks/stage2_peers.py) reweighted per channel to the ML optimum, from casest's stage-1 point
COLD_SCIPY_SCRIPT = """
import json, sys, time
sys.path.insert(0, sys.argv[2])
import numpy as np
import casest
import bench_stage2
from casest.models import model_file_hooks
module = casest.load_model_file("pitot5hole")
hooks = model_file_hooks(module)
data = module.simulate(0)
stage1, data = hooks.stage_data(data) if hooks.stage_data is not None else (None, data)
model = module.model()
start = np.array(json.loads(sys.argv[1]))
t0 = time.perf_counter()
from scipy.optimize import least_squares  # noqa: F401
t_import = time.perf_counter() - t0
t0 = time.perf_counter()
theta, c_fit = bench_stage2.scipy_fit(model, data, start, "analytic", True, clock=time.process_time)
t_call = time.perf_counter() - t0
print(json.dumps({"import": t_import, "fit_cpu": c_fit, "call": t_call}))
"""


def cold_process(env: dict) -> dict:
    """One fresh process of ``COLD_SCRIPT`` (casest's import, first, fresh-object and warm estimates)."""
    import json
    import subprocess
    import tempfile

    out = subprocess.run([sys.executable, "-c", COLD_SCRIPT], env=env, capture_output=True, text=True,
                         check=True, cwd=tempfile.gettempdir())
    return json.loads(out.stdout.strip().splitlines()[-1])


#: the peer's BLAS on one thread: its faster setting on this problem (first fit 0.15 s; with
#: OpenBLAS's threads on both cores 0.25-0.34 s, measured on the 2-core machine of the page)
PEER_BLAS_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def cold_scipy_process(env: dict, start) -> dict:
    """One fresh process of ``COLD_SCIPY_SCRIPT`` (SciPy's import and first fit from ``start``),
    its BLAS on one thread (``PEER_BLAS_ENV``)."""
    import json
    import subprocess
    import tempfile

    env = {**env, **PEER_BLAS_ENV}
    out = subprocess.run([sys.executable, "-c", COLD_SCIPY_SCRIPT, json.dumps(list(start)),
                          os.path.dirname(os.path.abspath(__file__))], env=env, capture_output=True, text=True,
                         check=True, cwd=tempfile.gettempdir())
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_cold(quick: bool) -> None:
    import tempfile

    say("## Cold start (Pitot default: the model file's record and manoeuvre windows, `casest solve pitot5hole`)")
    say()
    say("Each row is a fresh process (`python -c`); the compile cache is a private folder, empty for the first "
        "row and as the first row left it for the second. C compiles: libraries built by the compiler / taken "
        "from the cache.")
    say()
    say("| process | import casest s | first estimate s (built / cached) | fresh model object s (built / cached) | "
        "warm estimate s | success |")
    say("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "CASEST_CACHE_DIR": cache}
        for label in ("empty cache", "filled cache"):
            r = cold_process(env)

            def cell(key):
                t, stats, _ = r[key]
                return f"{t:.2f} ({stats['compiled'] + stats['rebuilt']} / {stats['hit']})"

            say(f"| {label} | {r['import']:.2f} | {cell('first')} | {cell('fresh_object')} | {r['warm'][0]:.2f} | "
                f"{all(r[k][2] for k in ('first', 'fresh_object', 'warm'))} |")
        peer = cold_scipy_process(env, r["stage1_point"])
    say()
    say(f"SciPy in a fresh process (BLAS on one thread, its faster setting here), from casest's best stage-1 point: "
        f"`import scipy.optimize` {peer['import']:.2f} s, "
        f"first `least_squares` fit (trf, NumPy Jacobian, reweighted to the ML optimum) {peer['fit_cpu']:.2f} CPU s "
        f"({peer['call']:.2f} s wall with the peer's residual functions built). casest's first estimate with the "
        f"cache filled (stage 1 included) / SciPy's first fit, CPU: {r['first_cpu'] / peer['fit_cpu']:.2f}.")
    say()


def scaling_one(N: int) -> dict:
    """Build and solve the full-mode Pitot NLP for N samples (run in a fresh process)."""
    from casest.two_stage.solve.nlps import sums_nlp

    module, model, data = pitot_data(N)
    part = casest.separate(model)
    start = model.vector(module.TRUTH) * 0.9
    settings = casest.SolverSettings()
    t = time.perf_counter()
    sums_nlp(model, part, N, "full", settings)
    build = time.perf_counter() - t
    # the same build again with the compile cache now filled (in-process caches cleared)
    casest._casadi.memory.clear_memory_caches()
    t = time.perf_counter()
    sums_nlp(model, part, N, "full", settings)
    rebuild = time.perf_counter() - t
    t = time.perf_counter()
    res = casest.solve_stage2(model, data, start, part, "full", settings)
    first = time.perf_counter() - t
    # again from the same start: the steady cost of a solve once the solver's memory exists
    t = time.perf_counter()
    res = casest.solve_stage2(model, data, start, part, "full", settings)
    solve = time.perf_counter() - t
    # VmHWM: this process's peak resident memory (ru_maxrss would include the parent's
    # peak, which survives fork and exec)
    with open("/proc/self/status") as status:
        hwm = next((int(line.split()[1]) for line in status if line.startswith("VmHWM")), 0)
    return {"N": N, "build": build, "rebuild": rebuild, "first": first, "solve": solve, "iterations": res.n_iterations, "success": res.success,
            "jit": settings.resolved_jit(N), "threads": settings.resolved_threads(N), "rss_mib": hwm / 1024}


def bench_scaling(quick: bool) -> None:
    import json
    import subprocess

    say("## Stage 2: time per IPOPT iteration against N (Pitot model, full mode)")
    say()
    say("Each N in a fresh process with an empty compile cache (peak RSS is that process's, data included); "
        "`SolverSettings()` defaults. "
        "Build: the NLP and its compiled sums; cached: the same build again in the same process with its "
        "in-process caches cleared and the compile cache filled. First solve: includes allocating the solver's work memory. "
        "Solve: the same solve again (whole `solve_stage2` call: start checks, IPOPT, cost at the end); "
        "s / iteration = solve / iterations.")
    say()
    say("| N | build s | build cached s | first solve s | solve s | iterations | s / iteration | JIT | threads | "
        "peak RSS MiB |")
    say("|---|---|---|---|---|---|---|---|---|---|")
    sizes = [100, 1000, 10000, 100000] + ([] if quick else [1000000])
    rows = []
    for N in sizes:
        cold_state()  # each N compiles into an empty cache: the build column includes its compiles
        out = subprocess.run([sys.executable, os.path.join(HERE, "bench.py"), "--scaling-one", str(N)],
                             capture_output=True, text=True, check=True)
        row = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append(row)
        per_iter = row["solve"] / max(row["iterations"], 1)
        say(f"| {N} | {row['build']:.2f} | {row['rebuild']:.2f} | {row['first']:.2f} | {row['solve']:.2f} | {row['iterations']} | {per_iter:.4f} | "
            f"{'yes' if row['jit'] else 'no'} | {row['threads']} | {row['rss_mib']:.0f} |")
    n = np.array([r["N"] for r in rows], dtype=float)
    per = np.array([r["solve"] / max(r["iterations"], 1) for r in rows])
    big = n >= 10000
    slope = np.polyfit(np.log(n[big]), np.log(per[big]), 1)[0] if big.sum() >= 2 else float("nan")
    say()
    say(f"Log-log slope of time per iteration against N (N >= 1e4, same JIT/thread settings): {slope:.3f}.")
    say()
