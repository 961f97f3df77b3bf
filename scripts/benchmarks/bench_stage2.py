"""Stage 2 of scripts/benchmarks/bench.py: casest against SciPy and lmfit on scalar 2, Pitot and NIST."""

from __future__ import annotations

import glob
import os
import time
import warnings

import numpy as np

from bench_common import REPO, cold_state, say

import casest  # noqa: E402


def residual_functions(model, data, start):
    """The peers' NumPy residual and hand-written Jacobian (scripts/benchmarks/stage2_peers.py), checked against
    casest's at the start: no CasADi call inside the peers' fits."""
    import stage2_peers

    pitot = casest.load_model_file(os.path.join(REPO, "models", "pitot5hole.py")) if model.name == "pitot5hole" \
        else None
    return stage2_peers.checked_problem(model, data, np.clip(start, model.lower_bounds, model.upper_bounds), pitot)


def _reweighted(fit, model, data, start, res, rounds: int = 50, clock=time.perf_counter):
    """ML by per-channel reweighting: weighted LS with w_j = 1/sqrt(R_j), R from the (NumPy) residuals."""
    ny = model.n_outputs
    if ny == 1:
        return fit(start, np.ones(1))
    weights, theta, total = np.ones(ny), start, 0.0
    for _ in range(rounds):
        theta, dt = fit(theta, weights)
        t = clock()
        ms = np.mean(res(theta).reshape(-1, ny) ** 2, axis=0)
        total += dt + clock() - t
        new = 1.0 / np.sqrt(np.maximum(ms, 1e-300))
        if np.allclose(new, weights, rtol=1e-10):
            break
        weights = new
    return theta, total


def scipy_fit(model, data, start, jac: str, ml: bool, max_nfev: int = 20000, clock=time.perf_counter):
    """scipy.optimize.least_squares, trf, x_scale='jac', tolerances 1e-15, at most ``max_nfev`` evaluations;
    the fit's time by ``clock`` (``time.process_time`` for CPU seconds)."""
    from scipy.optimize import least_squares

    res, jac_fn = residual_functions(model, data, start)
    lb, ub = model.lower_bounds, model.upper_bounds
    inner_lb = np.where(np.isfinite(lb), lb + 1e-10 * np.maximum(1, np.abs(lb)), lb)
    inner_ub = np.where(np.isfinite(ub), ub - 1e-10 * np.maximum(1, np.abs(ub)), ub)

    def fit(theta, weights):
        w = np.tile(weights, data.n_samples)
        theta = np.clip(theta, inner_lb, inner_ub)  # trf needs a strictly feasible start
        t = clock()
        out = least_squares(lambda th: res(th) * w, theta,
                            jac=(lambda th: jac_fn(th) * w[:, None]) if jac == "analytic" else "2-point",
                            bounds=(lb, ub), method="trf", x_scale="jac", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                            max_nfev=max_nfev)
        return out.x, clock() - t

    return _reweighted(fit, model, data, start, res, clock=clock) if ml else fit(start, np.ones(model.n_outputs))


def lmfit_fit(model, data, start, jac: str, ml: bool, clock=time.perf_counter):
    """lmfit leastsq (MINPACK LM; bounds by lmfit's transform), Dfun analytic or its default
    finite differences (epsfcn 1e-10), tolerances 1e-15; the fit's time by ``clock``."""
    import lmfit

    res, jac_fn = residual_functions(model, data, start)
    names = model.parameter_names

    def fit(theta, weights):
        w = np.tile(weights, data.n_samples)
        params = lmfit.Parameters()
        for p, s in zip(model.parameters, theta):
            params.add(p.name, value=float(np.clip(s, p.lb, p.ub)), min=p.lb, max=p.ub)

        def vec(pars):
            return np.array([pars[n].value for n in names])

        kws = {"Dfun": lambda pars: jac_fn(vec(pars)) * w[:, None]} if jac == "analytic" else {}
        t = clock()
        out = lmfit.minimize(lambda pars: res(vec(pars)) * w, params, method="leastsq", xtol=1e-15, ftol=1e-15,
                             max_nfev=20000, **kws)
        return vec(out.params), clock() - t

    return _reweighted(fit, model, data, start, res, clock=clock) if ml else fit(start, np.ones(model.n_outputs))


def _stage2_problems():
    """name -> builder of a fresh (model, data, stage-1 data, certified values, sweep settings)."""
    from casest.apps.nist import read_nist

    out = {}
    scalar2 = casest.load_model_file(os.path.join(REPO, "models", "scalar2.py"))
    out["scalar2"] = lambda: (scalar2.model(), scalar2.simulate(0), None, None, None)
    pitot = casest.load_model_file(os.path.join(REPO, "models", "pitot5hole.py"))
    windows = pitot.stage_data(pitot.simulate(39001))

    def pitot_problem():
        model = pitot.model()
        stage1, stage2 = (casest.Dataset.from_arrays(model, d.signals, d.outputs) for d in windows)
        return model, stage2, stage1, None, pitot.SWEEP_SETTINGS

    out["pitot (stage-2 windows)"] = pitot_problem
    for path in sorted(glob.glob(os.path.join(REPO, "data", "nist_strd", "*.dat"))):
        for start in (1, 2):
            name = f"{os.path.basename(path)[:-4]}/{start}"
            out[name] = lambda path=path, start=start: (lambda pr: (pr.model, pr.data, None, pr.certified, None))(
                read_nist(path, start=start))
    return out


def bench_stage2(quick: bool) -> None:
    from casest.apps.baselines import concentrated_cost
    from casest.apps.nist import log_relative_error

    say("## Stage 2 against SciPy and lmfit")
    say()
    say("Every method starts from the model's nominal values (NIST: the start named after the slash) inside the "
        "same box. casest's pipeline adds its stage 1; \"casest s2\" is stage 2 alone (full mode) from the nominal "
        "values. **cold** = casest's in-process caches cleared and an empty compile cache (NLP build and every "
        "compile included; CasADi and IPOPT already loaded, as SciPy is for its peers); **warm** = the same call again on "
        "the same model and data. SciPy: `least_squares(method='trf', x_scale='jac', xtol=ftol=gtol=1e-15)`; lmfit "
        "1.3: `minimize(method='leastsq', xtol=ftol=1e-15)` (bounds through lmfit's transform); each with the model "
        "and its exact Jacobian written by hand in NumPy (`an`, `scripts/benchmarks/stage2_peers.py`, checked against casest's "
        "at the start; no CasADi call in the peers) and with finite differences of the NumPy residual (`fd`: SciPy "
        "'2-point', lmfit's default epsfcn). On the "
        "multi-channel Pitot problem every method is judged by the same criterion, the ML cost with unknown diagonal "
        "R (paper Eq. 6), and the peers also get that problem by per-channel reweighting to convergence (`ML` "
        "rows), beside their plain least squares (which minimises another criterion).")
    say()
    say("Correct = NIST: >= 6 correct digits of every certified value; otherwise within 1e-6 relative of the lowest "
        "ML cost any method found.")
    say()
    try:
        import lmfit  # noqa: F401

        have_lmfit = True
    except ImportError:
        have_lmfit = False
        say("(lmfit is not installed: `pip install lmfit` adds its columns.)")
        say()
    methods = ["pipeline", "s2", "scipy an", "scipy fd"] + (["lmfit an", "lmfit fd"] if have_lmfit else [])
    say("| problem | pipeline cold s | pipeline warm s | s2 cold s | s2 warm s | scipy an s | scipy fd s | "
        + ("lmfit an s | lmfit fd s | " if have_lmfit else "") + "correct: " + " / ".join(methods) + " |")
    say("|---|---|---|---|---|---|---|" + ("---|---|" if have_lmfit else "") + "---|")
    totals = {m: 0 for m in methods}
    warm_to_correct, cold_to_correct = [], []
    problems = _stage2_problems()
    for name, build in problems.items():
        model, data, stage1, certified, sweep_settings = build()
        start = model.nominal
        fits, times = {}, {}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for label in ("cold", "warm"):
                if label == "cold":
                    cold_state()
                t = time.perf_counter()
                est = casest.estimate(model, data, stage1_data=stage1, sweep_settings=sweep_settings)
                times[f"pipeline {label}"] = time.perf_counter() - t
            fits["pipeline"] = est.theta
            model, data, stage1, certified, sweep_settings = build()
            for label in ("cold", "warm"):
                if label == "cold":
                    cold_state()
                t = time.perf_counter()
                s2 = casest.solve_stage2(model, data, np.clip(start, model.lower_bounds, model.upper_bounds), mode="full")
                times[f"s2 {label}"] = time.perf_counter() - t
            fits["s2"] = s2.theta
            ml = model.n_outputs > 1
            for jac in ("analytic", "2-point"):
                key = "an" if jac == "analytic" else "fd"
                fits[f"scipy {key}"], times[f"scipy {key}"] = scipy_fit(model, data, start, jac, False)
                if have_lmfit:
                    fits[f"lmfit {key}"], times[f"lmfit {key}"] = lmfit_fit(model, data, start, jac, False)
                if ml:
                    fits[f"scipy {key} ML"], times[f"scipy {key} ML"] = scipy_fit(model, data, start, jac, True)
                    if have_lmfit:
                        fits[f"lmfit {key} ML"], times[f"lmfit {key} ML"] = lmfit_fit(model, data, start, jac, True)
        if certified is not None:
            ok = {k: bool(log_relative_error(v, certified).min() >= 6) for k, v in fits.items()}
        else:
            costs = {k: concentrated_cost(model, data, v) for k, v in fits.items()}
            best = min(costs.values())
            ok = {k: bool(c <= best + 1e-6 * max(1, abs(best))) for k, c in costs.items()}
        rows = [(name, "")] + ([(name, " ML")] if model.n_outputs > 1 else [])
        for row_name, suffix in rows:
            peer = [f"scipy an{suffix}", f"scipy fd{suffix}"] + ([f"lmfit an{suffix}", f"lmfit fd{suffix}"] if have_lmfit else [])
            if suffix:
                cells = ["-", "-", "-", "-"] + [f"{times[k]:.3f}" for k in peer]
                flags = ["-", "-"] + ["yes" if ok[k] else "NO" for k in peer]
            else:
                cells = [f"{times[k]:.3f}" for k in ("pipeline cold", "pipeline warm", "s2 cold", "s2 warm")] + [
                    f"{times[k]:.3f}" for k in peer]
                flags = ["yes" if ok[k] else "NO" for k in ["pipeline", "s2"] + peer]
            label = row_name + (" (ML by reweighting)" if suffix else (" (plain LS for the peers)" if len(rows) > 1 else ""))
            say(f"| {label} | " + " | ".join(cells) + " | " + " / ".join(flags) + " |")
        ml_suffix = " ML" if model.n_outputs > 1 else ""
        for m in methods:
            key = m if m in ("pipeline", "s2") else m + ml_suffix
            totals[m] += ok[key]
        for store, suffix in ((cold_to_correct, "cold"), (warm_to_correct, "warm")):
            entry = {"s2": times[f"s2 {suffix}"] if ok["s2"] else np.inf,
                     "pipeline": times[f"pipeline {suffix}"] if ok["pipeline"] else np.inf}
            for m in methods[2:]:
                key = m + ml_suffix
                entry[m] = times[key] if ok[key] else np.inf
            store.append(entry)
    n = len(problems)
    say()
    say(f"Correct over {n} problems (the Pitot row by the ML criterion, peers reweighted): "
        + ", ".join(f"{m} {totals[m]}/{n}" for m in methods) + ".")
    say()
    for store, label in ((cold_to_correct, "cold"), (warm_to_correct, "warm")):
        for mine in ("pipeline", "s2"):
            for other in methods[2:]:
                ours = np.array([t[mine] for t in store])
                theirs = np.array([t[other] for t in store])
                both = np.isfinite(ours) & np.isfinite(theirs)
                if not both.any():
                    continue
                say(f"- {label} casest {mine} against {other}: no later on {int(np.sum(ours <= theirs))}/{n}; on the "
                    f"{both.sum()} problems both solve, total {ours[both].sum():.3f} s against {theirs[both].sum():.3f} s, "
                    f"median ratio {np.median(ours[both] / theirs[both]):.2f}.")
    say()


# ----------------------------------------------------------------------------- scaling
