"""Dynamic models in scripts/benchmarks/bench.py: stage 1 through the ODE, output error against SciPy."""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from bench_common import HERE, REPO, cold_state, say

import casest  # noqa: E402
from casest.two_stage.sweep import draw_candidates


def _short_period_record(n: int, seed: int):
    """A short-period record of n samples: the model file's input pattern repeated, fresh noise."""
    sp = casest.load_model_file(os.path.join(REPO, "models", "short_period.py"))
    model, exact = sp.model(), sp.model(substeps=8)
    t = np.arange(n) / sp.RATE
    u = sp.elevator(np.mod(t, sp.DURATION))
    blank = exact.dataset({"t": t, "delta_e": u, **{o: 0 * t for o in model.output_names}})
    _, clean = exact.simulate(sp.TRUTH, blank)
    z = clean + np.random.default_rng([seed, 5]).standard_normal(clean.shape) * [sp.NOISE_STD[o] for o in model.output_names]
    return sp, model, model.dataset({"t": t, "delta_e": u, **{o: z[:, j] for j, o in enumerate(model.output_names)}})


def output_error_one(n: int) -> dict:
    """Cold output-error stage 2 in this (fresh) process: build, compile, solve; then warm."""
    t0 = time.perf_counter()
    sp, model, data = _short_period_record(n, 0)
    t_data = time.perf_counter() - t0
    start = model.vector(sp.SINGLE_STAGE_START)
    t0 = time.perf_counter()
    cold = casest.solve_stage2(model, data, start, mode="full")
    t_cold = time.perf_counter() - t0
    _, _, data2 = _short_period_record(n, 1)
    t0 = time.perf_counter()
    warm = casest.solve_stage2(model, data2, start, mode="full")
    t_warm = time.perf_counter() - t0
    return {"cold": t_cold, "warm": t_warm, "data": t_data, "cold_success": bool(cold.success),
            "warm_success": bool(warm.success), "cost": float(cold.cost), "iterations": int(cold.n_iterations),
            "theta": [float(v) for v in cold.theta]}


def _scipy_output_error(sp, model, data, start):
    """The short-period output-error ML written with SciPy (the reference's time and optimum)."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import least_squares

    t, u, z = data.signals[:, 0], data.signals[:, 1], data.outputs
    V0 = sp.V0

    def simulate(theta):
        Za, Zd, Ma, Mq, Md = theta[:5]
        A = np.array([[Za, 1.0], [Ma, Mq]])
        s, out = np.zeros(12), [np.zeros(12)]  # x (2) and dx/d(Za, Zd, Ma, Mq, Md) (2 x 5)
        for i in range(t.size - 1):
            slope = (u[i + 1] - u[i]) / (t[i + 1] - t[i])

            def rhs(tt, s, i=i, slope=slope):
                de = u[i] + slope * (tt - t[i])
                x, S = s[:2], s[2:].reshape(2, 5)
                dS = A @ S
                dS[0, 0] += x[0]
                dS[0, 1] += de
                dS[1, 2] += x[0]
                dS[1, 3] += x[1]
                dS[1, 4] += de
                return np.concatenate([A @ x + np.array([Zd * de, Md * de]), dS.ravel()])

            s = solve_ivp(rhs, (t[i], t[i + 1]), s, method="DOP853", rtol=1e-10, atol=1e-12).y[:, -1]
            out.append(s)
        return np.array(out)

    def parts(theta):
        y = simulate(theta)
        x, S = y[:, :2], y[:, 2:].reshape(-1, 2, 5)
        Za, Zd, *_ = theta[:5]
        pred = np.column_stack([x[:, 0] + theta[5], x[:, 1] + theta[6], V0 * (Za * x[:, 0] + Zd * u)])
        J = np.zeros((t.size, 3, 7))
        J[:, 0, :5], J[:, 1, :5] = S[:, 0], S[:, 1]
        J[:, 0, 5], J[:, 1, 6] = 1.0, 1.0
        J[:, 2, :5] = V0 * Za * S[:, 0]
        J[:, 2, 0] += V0 * x[:, 0]
        J[:, 2, 1] += V0 * u
        return pred, J

    theta, R = np.asarray(start, dtype=float), np.var(z, axis=0)
    t0 = time.perf_counter()
    for _ in range(50):
        fit = least_squares(lambda th: ((z - parts(th)[0]) / np.sqrt(R)).ravel(), theta,
                            jac=lambda th: -(parts(th)[1] / np.sqrt(R)[None, :, None]).reshape(-1, 7),
                            bounds=(model.lower_bounds, model.upper_bounds), x_scale=model.scales,
                            xtol=1e-10, ftol=1e-10, gtol=1e-10)
        theta = fit.x
        R_new = np.mean((z - parts(theta)[0]) ** 2, axis=0)
        settled = np.all(np.abs(R_new - R) < 1e-8 * R)
        R = R_new
        if settled:
            break
    return theta, time.perf_counter() - t0


def bench_dynamic(quick: bool) -> None:
    import json
    import subprocess

    from casest.two_stage.sweep.dynamic_evaluators import DynamicGramEvaluator

    say("## Dynamic models")
    say()
    dc = casest.load_model_file(os.path.join(REPO, "models", "data_compatibility.py"))
    dc.WINDOW = (500.0, 600.0)  # 100 s at 50 Hz: N = 5001
    model, data = dc.model(), dc.simulate(0)
    part = casest.separate(model)
    K = 1024 if quick else 4096
    cands, _, _ = draw_candidates(model, part, casest.SweepSettings(design="sobol", n_candidates=K, seed=0))
    say(f"Stage 1 through the ODE: data compatibility (6 states, RK4), N = {data.n_samples}, {K} Sobol candidates "
        "of the six IMU biases; one simulation and Gram sum per candidate.")
    say()
    say("| evaluation | build + compile s | sweep s | candidate x sample per s |")
    say("|---|---|---|---|")
    for label, jit, threads in (("CasADi VM, 1 thread", False, 1), ("compiled, 1 thread", True, 1),
                                ("compiled, 2 threads", True, 2)):
        if not jit and not quick:
            subset = cands[: K // 8]  # the VM is slow: time an eighth of the candidates
        else:
            subset = cands
        t0 = time.perf_counter()
        ev = DynamicGramEvaluator(model, part, data, len(subset), jit=jit, threads=threads)
        t_build = time.perf_counter() - t0
        t0 = time.perf_counter()
        ev.solve(subset)
        t_sweep = time.perf_counter() - t0
        say(f"| {label} ({len(subset)} candidates) | {t_build:.2f} | {t_sweep:.2f} | "
            f"{len(subset) * data.n_samples / t_sweep:.3g} |")
    say()
    n = 2000 if quick else 10000
    cold_state()  # the subprocess inherits the empty compile cache
    out = subprocess.run([sys.executable, os.path.join(HERE, "bench.py"), "--output-error-one", str(n)], capture_output=True,
                         text=True, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    sp, model_sp, data_sp = _short_period_record(n, 0)
    start = model_sp.vector(sp.SINGLE_STAGE_START)
    theta_ref, t_ref = _scipy_output_error(sp, model_sp, data_sp, start)
    prob = casest.Problem(model_sp, data_sp)
    say(f"Output-error stage 2, short-period model (2 states, 7 parameters, 3 outputs), N = {n}, from the same "
        "start (the model file's guess), R unknown (ML):")
    say()
    say("| method | seconds | ML cost (profile) | converged |")
    say("|---|---|---|---|")
    say(f"| casest cold (fresh process: build, compile, {res['iterations']} iterations) | {res['cold']:.2f} | "
        f"{prob.profile_cost(res['theta']):.10g} | {res['cold_success']} |")
    say(f"| casest warm (next record, same process) | {res['warm']:.2f} | - | {res['warm_success']} |")
    say(f"| SciPy solve_ivp + least_squares (exact sensitivities), reweighted | {t_ref:.2f} | "
        f"{prob.profile_cost(theta_ref):.10g} | - |")
    say()
    say(f"Ratios: SciPy / casest cold {t_ref / res['cold']:.1f}x, SciPy / casest warm {t_ref / res['warm']:.1f}x.")
    say()
