"""The measurements behind the benchmark claims (``scripts/benchmarks/claims.py``).

Each function runs casest and its peer interleaved, times each in CPU seconds
(``time.process_time``: every thread of this process; a contender in its own process: that
process's CPU seconds), alternates which contender goes first (from call to call in one
process, from run to run, by the run's index, where each contender is a process of its own),
counts each contender's fastest of ``REPEATS`` calls after a first call that is not counted, and
returns its figures. CPU time, not wall time, so that a claim holds on a machine busy with
other work. "Warm" means what a user's later calls find: the first call built and compiled what
casest compiles, and the compile cache holds the libraries (casest compiles a small problem's
residual library in the background once it pays; here it is compiled before timing, as a
later session would find it).
"""

from __future__ import annotations

import glob
import os
import subprocess
import tempfile
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.abspath(os.path.join(HERE, "..", ".."))

#: timed calls of each contender (the fastest counts), after one uncounted call
REPEATS = 5


def cpu_seconds(fun) -> float:
    """The CPU seconds of this process (all its threads) spent in ``fun()``."""
    t = time.process_time()
    fun()
    return time.process_time() - t


def interleaved(contenders: dict, repeats: int = REPEATS) -> dict:
    """Each contender's fastest of ``repeats`` calls, the contenders called in turn and the order
    reversed every round.

    Parameters
    ----------
    contenders : dict
        name -> a function of no argument returning the CPU seconds of its call (wrap a plain
        call in :func:`cpu_seconds`).
    repeats : int
        Rounds.

    Returns
    -------
    dict
        name -> its fastest CPU seconds.
    """
    names = list(contenders)
    best = dict.fromkeys(names, np.inf)
    for k in range(repeats):
        for name in names if k % 2 == 0 else names[::-1]:
            best[name] = min(best[name], contenders[name]())
    return best


def _nist_problems() -> list:
    from casest.apps.nist import read_nist

    out = []
    for path in sorted(glob.glob(os.path.join(REPO, "data", "nist_strd", "*.dat"))):
        for start in (1, 2):
            out.append((f"{os.path.basename(path)[:-4]}/{start}", read_nist(path, start=start)))
    return out


def _compile_residuals(model, data) -> None:
    """The small-problem residual library compiled now (what the compile cache holds in a later session)."""
    from casest.backend.ipopt import SolverSettings
    from casest.two_stage.solve.levenberg_marquardt import prediction_function

    prediction_function(model, data.n_samples, SolverSettings()).compile_now()


def stage2_nist(run: int = 0) -> dict:
    """casest's stage 2 alone (``solve_stage2``, full mode, warm) against SciPy's ``least_squares``
    (trf, ``x_scale='jac'``, tolerances 1e-15) and lmfit's ``leastsq`` (tolerances 1e-15), both with
    the exact Jacobian written in NumPy (``stage2_peers.py``), from the NIST start inside the same
    box, on the 24 NIST rows. casest's time is the whole call (checks, start cost, covariance-free
    result); the peers' the solver call only (their residual functions and lmfit's Parameters are
    built outside the timing). Rows where a contender misses the certified values (6 digits) are
    left out of its ratio. ``run``: unused (the order alternates within the process)."""
    import casest
    from bench_stage2 import lmfit_fit, scipy_fit
    from casest.apps.nist import log_relative_error

    over_lmfit, over_scipy, slower_scipy, slower_lmfit = [], [], 0, 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, pr in _nist_problems():
            model, data = pr.model, pr.data
            start = np.clip(model.nominal, model.lower_bounds, model.upper_bounds)
            casest.solve_stage2(model, data, start, mode="full")
            _compile_residuals(model, data)
            fits = {"casest": casest.solve_stage2(model, data, start, mode="full").theta}

            def peer(name, fit):
                fits[name], seconds = fit(model, data, start, "analytic", False, clock=time.process_time)
                return seconds

            times = interleaved({
                "casest": lambda: cpu_seconds(lambda: casest.solve_stage2(model, data, start, mode="full")),
                "scipy": lambda: peer("scipy", scipy_fit), "lmfit": lambda: peer("lmfit", lmfit_fit)})
            ok = {k: bool(log_relative_error(v, pr.certified).min() >= 6) for k, v in fits.items()}
            if ok["casest"] and ok["scipy"]:
                over_scipy.append(times["casest"] / times["scipy"])
                slower_scipy += times["casest"] > times["scipy"]
            if ok["casest"] and ok["lmfit"]:
                over_lmfit.append(times["casest"] / times["lmfit"])
                slower_lmfit += times["casest"] > times["lmfit"]
    return {"over_lmfit": float(np.median(over_lmfit)), "over_scipy": float(np.median(over_scipy)),
            "slower_than_scipy": float(slower_scipy), "slower_than_lmfit": float(slower_lmfit)}


def pipeline_nist(run: int = 0) -> dict:
    """casest's whole pipeline (``estimate``: stage 1, the starts its evidence calls for, the
    covariance and checks), warm, against one SciPy trf fit from the NIST start with the exact
    Jacobian: the median over the 24 NIST rows of the time ratio."""
    import casest
    from bench_stage2 import scipy_fit

    ratios = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, pr in _nist_problems():
            model, data = pr.model, pr.data
            casest.estimate(model, data)
            _compile_residuals(model, data)
            casest.estimate(model, data)
            start = np.asarray(model.nominal, dtype=float)
            times = interleaved({
                "casest": lambda: cpu_seconds(lambda: casest.estimate(model, data)),
                "scipy": lambda: scipy_fit(model, data, start, "analytic", False, clock=time.process_time)[1]})
            ratios.append(times["casest"] / times["scipy"])
    return {"over_scipy": float(np.median(ratios))}


def ekf(run: int = 0) -> dict:
    """casest's compiled EKF pass (``ExtendedKalmanFilter.filter``, warm, results kept) against the
    same EKF as a numba-compiled loop over scalars (``ekf_numba_peer.py``, written for the
    pendulum only), on the pendulum records of ``bench_filters.py``, N = 1e2, 1e3, 1e4, 1e5, 1e6;
    at 1e6 also casest's pass written into the arrays of its previous one (``filter(data,
    out=...)``), as a loop over records of one length runs."""
    import bench_filters as bf
    import ekf_numba_peer
    from casest.filters.ekf import ExtendedKalmanFilter

    model = bf.pendulum()
    loop = ekf_numba_peer.ekf_pass_factory()
    out = {}
    for n in (100, 1000, 10000, 100000, 1000000):
        data = bf.record(model, n, 2)
        ekf_ = ExtendedKalmanFilter(model, bf.THETA, {"rate": bf.Q_RATE}, [bf.R_VAR] * 2, bf.P0)
        args = (np.ascontiguousarray(data.outputs), np.ascontiguousarray(data.signals[:, 1]), bf.THETA["c"],
                bf.THETA["L"], bf.Q_RATE, bf.R_VAR, float(bf.P0[0, 0]))
        ekf_.filter(data)
        loop(*args)
        times = interleaved({"casest": lambda: cpu_seconds(lambda: ekf_.filter(data)),
                             "numba": lambda: cpu_seconds(lambda: loop(*args))}, _ekf_repeats(n))
        out[f"over_numba_{n}"] = times["casest"] / times["numba"]
        if n == 1000000:
            earlier = ekf_.filter(data)
            times = interleaved({"casest": lambda: cpu_seconds(lambda: ekf_.filter(data, out=earlier)),
                                 "numba": lambda: cpu_seconds(lambda: loop(*args))}, _ekf_repeats(n))
            out[f"out_over_numba_{n}"] = times["casest"] / times["numba"]
    return out


def _ekf_repeats(n: int) -> int:
    """Rounds for a record of ``n`` samples: short passes last well under a millisecond, so more
    of them (the fastest of many is stable where one call is at the clock's mercy)."""
    return max(REPEATS, int(2e5 // n))


def stage1(run: int = 0) -> dict:
    """casest's stage-1 sweep (``GramEvaluator``, the default settings' compile choice, one thread)
    against the NumPy peer (``stage1_peers.NumpySweep``: the Pitot algebra reduced by hand to BLAS
    products, one thread) on the Pitot model, N = 1e3, K = 5000 random candidates; and N = 100,
    K = 100 (N K = 1e4, below the compile threshold: the Gram sums' library from the compile
    cache, where :func:`fill_cache_for_stage1` put it, as ``SweepSettings()`` uses it)."""
    import casest
    import stage1_peers as peers
    from bench_common import pitot_data
    from bench_stage1 import pitot_sweep_inputs
    from casest.two_stage.sweep.candidates import draw_candidates
    from casest.two_stage.sweep.evaluators import GramEvaluator, evaluate_candidates

    out = {}
    for n, k in ((1000, 5000), (100, 100)):
        module, model, data = pitot_data(n)
        part = casest.separate(model)
        cands, _, _ = draw_candidates(model, part, casest.SweepSettings(design="random", n_candidates=k, seed=1))
        evaluator = GramEvaluator(part, data, k, jit=casest.SweepSettings().resolved_jit(n, k), threads=1, cached=True)
        numpy_sweep = peers.NumpySweep(peers.peer_inputs(pitot_sweep_inputs(module, data)), chunk=8)
        evaluate_candidates(evaluator, data.outputs, cands)
        numpy_sweep.trace(cands, 1)
        reps = max(1, int(2e6 // (n * k)))  # a call of a few ms at least

        def many(call):
            return lambda: cpu_seconds(lambda: [call() for _ in range(reps)]) / reps

        times = interleaved({"casest": many(lambda: evaluate_candidates(evaluator, data.outputs, cands)),
                             "numpy": many(lambda: numpy_sweep.trace(cands, 1))})
        out[f"numpy_over_casest_{n}_{k}"] = times["numpy"] / times["casest"]
    return out


def fill_cache_for_stage1() -> None:
    """One sweep at the compile threshold: the compile cache then holds the Gram sums' library."""
    import casest
    from bench_common import pitot_data
    from casest.two_stage.sweep.evaluators import GramEvaluator

    module, model, data = pitot_data(1000)
    GramEvaluator(casest.separate(model), data, 1000, jit=True)


_AP2 = [sys.executable, os.path.join(REPO, "scripts", "examples", "ampyx_example.py"), "--no-figures"]


_REFERENCE = [sys.executable, os.path.join(HERE, "reference_workload.py")]


def ap2_example(run: int = 0) -> dict:
    """The AP2 worked example (``scripts/examples/ampyx_example.py --no-figures``) as a whole
    process with the compile cache filled (by :func:`fill_cache_for_ap2`, once before the runs)
    against the fixed reference workload (``reference_workload.py``: SciPy fits of the NIST rows)
    in a process of its own, the order reversed on odd ``run``; each process's CPU seconds (with
    the children it waited for). No peer runs the whole example: the reference workload is the
    unit that cancels the machine's drift in speed and the cost of busy neighbours. Figures: the
    example / the reference, and each one's CPU seconds."""
    from bench_output_error import children_cpu_seconds

    def cpu_of(command) -> float:
        before = children_cpu_seconds()
        subprocess.run(command, capture_output=True, check=True, cwd=REPO)
        return children_cpu_seconds() - before

    if run % 2 == 0:
        example, reference = cpu_of(_AP2), cpu_of(_REFERENCE)
    else:
        reference, example = cpu_of(_REFERENCE), cpu_of(_AP2)
    return {"over_reference": example / reference, "cpu_seconds": example, "reference_cpu_seconds": reference}


def fill_cache_for_ap2() -> None:
    """One uncounted run of the AP2 example: the compile cache then holds its libraries."""
    subprocess.run(_AP2, capture_output=True, check=True, cwd=REPO)


#: the aircraft output-error case of ``bench_output_error.py`` (record, start), made once per ``record``/``check``
_OE_CASE = os.path.join(tempfile.gettempdir(), "casest_claims_output_error_case.npz")


def make_output_error_case() -> None:
    """The aircraft output-error case (the two-step method's start on the simulated flight), once."""
    from bench_output_error import make_case

    make_case(_OE_CASE)


#: the JAX peer on one thread (XLA's CPU thread pools off): its least CPU time
JAX_ONE_THREAD = {"XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1",
                  "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


def output_error_jax(run: int = 0) -> dict:
    """The 38-parameter aircraft output error (``bench_output_error.py``'s case) by casest's
    Gauss-Newton (a whole estimate: the covariance and the residual checks included; with the
    default exact-Hessian covariance and with the Gauss-Newton one the peer reports) against JAX +
    SciPy's ``least_squares`` (the fit alone; JAX on one thread, ``JAX_ONE_THREAD``), each in a
    fresh process: cold (casest with an empty compile cache, its compiler's CPU included; JAX's
    first jit) and warm (the same call again in that process). Ratios of CPU seconds JAX / casest
    (above 1: casest faster); the processes' order reversed on odd ``run``."""
    from bench_output_error import run_child

    with tempfile.TemporaryDirectory(prefix="casest_claims_oe_") as folder:
        kinds = {"default": lambda: run_child("gauss-newton", _OE_CASE, os.path.join(folder, "cache_default")),
                 "gn_cov": lambda: run_child("gauss-newton-gn-cov", _OE_CASE, os.path.join(folder, "cache_gn_cov")),
                 "jax": lambda: run_child("jax", _OE_CASE, None, JAX_ONE_THREAD)}
        order = list(kinds) if run % 2 == 0 else list(kinds)[::-1]
        r = {kind: kinds[kind]() for kind in order}
    return {"jax_over_default_warm": r["jax"]["warm"]["cpu"] / r["default"]["warm"]["cpu"],
            "jax_over_gn_cov_warm": r["jax"]["warm"]["cpu"] / r["gn_cov"]["warm"]["cpu"],
            "jax_over_gn_cov_cold": r["jax"]["cold"]["cpu"] / r["gn_cov"]["cold"]["cpu"]}


def stage1_memory(run: int = 0) -> dict:
    """Stage 1's memory at N = 1e6 on the Pitot model, 500 candidates: a fresh process's *first*
    sweep (``stage1_memory.py``: nothing run before it, so its imports, builds and compiled
    libraries count), the peak RSS above the loaded record (whole MiB) and the peak above the
    process before the record over the record's size (two decimals)."""
    import stage1_memory

    r = stage1_memory.measure(1000000, 500, HERE, sweeps=("first",))
    first = r["first"]
    # the resolution the page states (whole MiB, two decimals): the same sweep's RSS drifts by
    # about 1 MiB within an hour on the machine of the page
    return {"first_above_record_mib_1e6": float(round(first["peak"] - first["loaded"])),
            "first_over_record_1e6": round((first["peak"] - first["base"]) / r["record"], 2)}


#: the compile cache the cold-start runs share (filled once by :func:`fill_cache_for_cold_start`)
_COLD_CACHE = os.path.join(tempfile.gettempdir(), "casest_claims_cold_cache")


#: casest's best stage-1 point on the Pitot default (SciPy's start), written by :func:`fill_cache_for_cold_start`
_COLD_START_POINT = os.path.join(tempfile.gettempdir(), "casest_claims_cold_start_point.json")


def cold_start(run: int = 0) -> dict:
    """The Pitot default (``casest solve pitot5hole``'s record and windows) in fresh processes with
    the compile cache filled: the CPU seconds of casest's first estimate in its process (stage 1,
    every start, the covariance) over those of SciPy's first ``least_squares`` fit in its own
    process (trf, NumPy Jacobian, reweighted to the ML optimum, from casest's best stage-1 point,
    BLAS on one thread, its faster setting here: ``bench_cold.py``), the processes' order reversed
    on odd ``run``."""
    import json

    from bench_cold import cold_process, cold_scipy_process

    env = {**os.environ, "CASEST_CACHE_DIR": _COLD_CACHE}
    with open(_COLD_START_POINT) as fh:
        point = json.load(fh)
    if run % 2 == 0:
        ours, peer = cold_process(env), cold_scipy_process(env, point)
    else:
        peer, ours = cold_scipy_process(env, point), cold_process(env)
    return {"first_over_scipy_first": ours["first_cpu"] / peer["fit_cpu"]}


def fill_cache_for_cold_start() -> None:
    """One uncounted cold-start process: the shared compile cache then holds its libraries, and
    its best stage-1 point is kept for SciPy's start."""
    from casest.data import atomic_write_text
    from bench_cold import cold_process
    import json

    ours = cold_process({**os.environ, "CASEST_CACHE_DIR": _COLD_CACHE})
    atomic_write_text(_COLD_START_POINT, json.dumps(ours["stage1_point"]))


#: ``import casest`` and the import of what it loads (NumPy and CasADi; SciPy only when a call needs it)
_IMPORTS = {"casest": "import casest", "dependencies": "import numpy, casadi"}
#: fresh processes of each import (the fastest counts): one import is ~0.2-0.4 s and varies by a third
IMPORT_REPEATS = 9


def import_cost(run: int = 0) -> dict:
    """``import casest`` in a fresh process against the import of the libraries it loads (NumPy
    and CasADi) in another, CPU seconds of the import statement, each the fastest of
    ``IMPORT_REPEATS`` fresh processes, the two alternated (the first on odd ``run`` reversed). Figure: casest's
    import / its dependencies' (above 1: what casest's own modules add)."""
    best = {name: float("inf") for name in _IMPORTS}
    names = list(_IMPORTS) if run % 2 == 0 else list(_IMPORTS)[::-1]
    for k in range(IMPORT_REPEATS):
        for name in names if k % 2 == 0 else names[::-1]:
            code = f"import time\nc = time.process_time()\n{_IMPORTS[name]}\nprint(time.process_time() - c)"
            done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                  cwd=tempfile.gettempdir())
            best[name] = min(best[name], float(done.stdout.strip().splitlines()[-1]))
    return {"import_over_dependencies": best["casest"] / best["dependencies"], "import_cpu_seconds": best["casest"],
            "dependencies_cpu_seconds": best["dependencies"]}


def profile_lmfit(run: int = 0) -> dict:
    """casest's 95 % profile intervals of every parameter against lmfit's ``conf_interval`` given
    the same statistic and the model's residual in NumPy (``profile_peer.py``: paper scalar
    examples 1 and 2, NIST Misra1a, Rat42 and MGH09 from start 1; lmfit's time includes its own
    fit), warm, interleaved with the order alternated, CPU seconds, the fastest of 3 each: the median
    over the problems of lmfit / casest and the number of problems where lmfit is faster."""
    import profile_peer

    ratios = [theirs / ours for _, _, ours, theirs, _ in profile_peer.compare(3, clock=time.process_time)]
    return {"lmfit_over_casest": float(np.median(ratios)), "lmfit_faster": float(sum(r < 1 for r in ratios))}


MEASUREMENTS = {"stage2_nist": stage2_nist, "pipeline_nist": pipeline_nist, "ekf": ekf, "stage1": stage1,
                "ap2_example": ap2_example, "output_error_jax": output_error_jax, "stage1_memory": stage1_memory,
                "cold_start": cold_start, "import_cost": import_cost, "profile_lmfit": profile_lmfit}
#: what runs once before a measurement's runs (uncounted)
PREPARE = {"stage1": fill_cache_for_stage1, "ap2_example": fill_cache_for_ap2, "output_error_jax": make_output_error_case,
           "cold_start": fill_cache_for_cold_start}
