#!/usr/bin/env python3
"""Output error on a big model: casest (Gauss-Newton and IPOPT paths) against JAX + SciPy, one run.

    python3 scripts/benchmarks/bench_output_error.py [--parts small aircraft] [--skip-ipopt] [--out FILE.md]
    python3 scripts/benchmarks/bench_output_error.py --parts spread [--repeats 7]   (identical warm calls)

small: the bundled dynamic model files (short period, data compatibility), whole estimates
with either stage-2 path, each in a fresh process. filter: filter-error ML on
``models/longitudinal.py`` in both formulations with both solvers.

The problem is that of ``scripts/examples/aircraft_two_step.py --output-error``: the 6-DOF aircraft
of ``models/aircraft.py`` (9 states, 38 parameters: 32 aerodynamic coefficients and 6 IMU
biases, 12 outputs), N = 3001 samples at 50 Hz, R diagonal and unknown (ML), started from
the two-step estimates. Each solver runs in a fresh process: cold (for casest an empty
compile cache; for JAX its first jit compile) and warm (the same solve again in that
process). Reported: wall and CPU seconds, the ML cost reached (the profile cost of
``casest.Problem``, the one yardstick), and peak memory.

The peer is written as a competent user would: the same RK4 step with linearly held
inputs in ``jax.lax.scan``, first-order sensitivities by ``jax.jacfwd`` of the jitted
residual, ``scipy.optimize.least_squares`` (trf, the same bounds, ``x_scale="jac"``,
tolerances 1e-12) with the residuals weighted by 1/sqrt(R_j), R re-estimated per channel
after each fit until it settles (the ML fixed point).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))

BIASES = ("l_x", "l_y", "l_z", "l_p", "l_q", "l_r")


def make_case(path: str) -> None:
    """The record, the initial state and the start (from the two-step method), saved to ``path``."""
    import casest
    from casest.apps.sim import aircraft as ac

    mf = casest.load_model_file(os.path.join(HERE, "..", "..", "models", "aircraft.py"))
    record = ac.simulate(0)
    _, _, smoothed = mf.reconstruct(record)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        two_step = casest.estimate(mf.model(), mf.regression_data(record, smoothed))
    x0 = np.concatenate([smoothed.x[0, :3], record.imu[0, 3:] - smoothed.x[0, 12:15], smoothed.x[0, 3:6]])
    data = mf.output_error_dataset(record, x0)
    model = mf.output_error_model()
    start = {**dict(zip(mf.model().parameter_names, two_step.theta)), **dict(zip(BIASES, smoothed.x[0, 9:15]))}
    np.savez(path, t=record.time, controls=record.controls, outputs=data.outputs, x0=x0,
             start=model.vector(start), record_seed=0)


def load_case(path: str):
    import casest
    from casest.apps.sim import aircraft as ac

    mf = casest.load_model_file(os.path.join(HERE, "..", "..", "models", "aircraft.py"))
    case = np.load(path)
    model = mf.output_error_model()
    cols = {"t": case["t"], **{n: case["controls"][:, k] for k, n in enumerate(ac.CONTROLS)}}
    cols.update({n: case["outputs"][:, j] for j, n in enumerate(model.output_names)})
    cols.update({n: np.full(case["t"].size, case["x0"][k]) for k, n in enumerate(("u", "v", "w", "p", "q", "r", "phi",
                                                                                   "theta", "psi"))})
    return model, model.dataset(cols), case["start"], case["x0"]


def child_casest(path: str, solver: str) -> dict:
    """Cold then warm ``casest.estimate`` (stage 2 from the start, and the covariance); ``solver``
    ``"gauss-newton"``, ``"ipopt"`` or ``"gauss-newton-gn-cov"`` (the Gauss-Newton covariance, as
    the peer would report)."""
    import casest
    from casest.backend.ipopt import SolverSettings

    model, data, start, _ = load_case(path)
    covariance = "gauss-newton" if solver.endswith("-gn-cov") else "hessian"
    settings = SolverSettings(output_error_solver=solver.replace("-gn-cov", ""))
    out = {}
    for label in ("cold", "warm"):
        t0, c0, compiler0 = time.perf_counter(), time.process_time(), children_cpu_seconds()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            est = casest.estimate(model, data, start=dict(zip(model.parameter_names, start)), mode="full",
                                  solver_settings=settings, covariance=covariance)
        out[label] = {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0 + children_cpu_seconds() - compiler0,
                      "success": bool(est.success), "iterations": int(est.n_iterations),
                      "theta": est.theta.tolist()}
    out["peak_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def children_cpu_seconds() -> float:
    """CPU seconds of finished child processes (the C compiler), since the process began."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def child_jax(path: str) -> dict:
    """The same ML fit written with JAX and SciPy (see the module docstring)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    from scipy.optimize import least_squares

    model, data, start, x0 = load_case(path)
    t, U, Z = data.signals[:, 0], data.signals[:, 1:5], data.outputs
    dt = float(t[1] - t[0])
    lb, ub = model.lower_bounds, model.upper_bounds
    rhs = _jax_rhs(jnp)

    def simulate(theta):
        c = theta[:32]

        def step(x, uu):
            ua, ub_ = uu
            um = 0.5 * (ua + ub_)
            k1 = rhs(x, ua, c)
            k2 = rhs(x + 0.5 * dt * k1, um, c)
            k3 = rhs(x + 0.5 * dt * k2, um, c)
            k4 = rhs(x + dt * k3, ub_, c)
            x1 = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            return x1, x1

        _, X = jax.lax.scan(step, jnp.asarray(x0), (jnp.asarray(U[:-1]), jnp.asarray(U[1:])))
        return jnp.vstack([jnp.asarray(x0)[None, :], X])

    outputs = _jax_outputs(jnp, rhs)

    def predict(theta):
        X = simulate(theta)
        return jax.vmap(lambda x, u: outputs(x, u, theta))(X, jnp.asarray(U))

    predict_jit = jax.jit(predict)
    jac_jit = jax.jit(jax.jacfwd(predict))
    out = {}
    for label in ("cold", "warm"):
        t0, c0 = time.perf_counter(), time.process_time()
        theta, R = np.asarray(start, dtype=float), None
        n_jac = 0
        for _ in range(50):
            y = np.asarray(predict_jit(theta))
            R_new = np.mean((Z - y) ** 2, axis=0)
            if R is not None and np.all(np.abs(R_new - R) <= 1e-10 * R):
                break
            R = R_new
            w = 1.0 / np.sqrt(R)
            fit = least_squares(lambda th: ((np.asarray(predict_jit(th)) - Z) * w).ravel(), theta,
                                jac=lambda th: (np.asarray(jac_jit(th)) * w[None, :, None]).reshape(-1, theta.size),
                                bounds=(lb, ub), method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)
            n_jac += fit.njev
            theta = fit.x
        out[label] = {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0, "jacobians": n_jac,
                      "theta": theta.tolist()}
    out["peak_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def _jax_rhs(jnp):
    """Eq. 6.16-6.22 of the aircraft model (``casest.apps.sim.aircraft.rigid_body``, 9 states) in JAX."""
    from casest.apps.sim import aircraft as ac

    af = ac.AIRFRAME
    inertia = jnp.asarray(af.inertia)

    def rhs(x, controls, c):
        u, v, w, p, q, r, phi, theta, _ = (x[i] for i in range(9))
        de, da, dr, Tc = (controls[i] for i in range(4))
        V = jnp.sqrt(u**2 + v**2 + w**2)
        alpha, beta = jnp.arctan2(w, u), jnp.arcsin(v / V)
        C = ac.coefficient_expressions(alpha, beta, V, p, q, r, de, da, dr, Tc, dict(zip(ac.COEFFICIENTS, c)), af)
        qS = 0.5 * af.rho * V**2 * af.S
        fx, fy, fz = qS * C["CX"] / af.mass, qS * C["CY"] / af.mass, qS * C["CZ"] / af.mass
        moments = jnp.stack([qS * af.b * C["Cl"], qS * af.cbar * C["Cm"], qS * af.b * C["Cn"]])
        omega = jnp.stack([p, q, r])
        omega_dot = jnp.linalg.solve(inertia, moments - jnp.cross(omega, inertia @ omega))
        sph, cph, sth, cth = jnp.sin(phi), jnp.cos(phi), jnp.sin(theta), jnp.cos(theta)
        return jnp.concatenate([jnp.stack([fx - q * w + r * v - ac.G * sth, fy - r * u + p * w + ac.G * cth * sph,
                                           fz - p * v + q * u + ac.G * cth * cph]), omega_dot,
                                jnp.stack([p + q * sph * sth / cth + r * cph * sth / cth, q * cph - r * sph,
                                           (q * sph + r * cph) / cth])])

    return rhs


def _jax_outputs(jnp, rhs):
    """The 12 outputs of ``models/aircraft.py::output_error_model`` in JAX."""
    from casest.apps.sim import aircraft as ac

    af = ac.AIRFRAME

    def outputs(x, controls, theta):
        u, v, w, p, q, r, phi, th, psi = (x[i] for i in range(9))
        de, da, dr, Tc = (controls[i] for i in range(4))
        V = jnp.sqrt(u**2 + v**2 + w**2)
        alpha, beta = jnp.arctan2(w, u), jnp.arcsin(v / V)
        C = ac.coefficient_expressions(alpha, beta, V, p, q, r, de, da, dr, Tc,
                                       dict(zip(ac.COEFFICIENTS, theta[:32])), af)
        qS = 0.5 * af.rho * V**2 * af.S
        b = theta[32:]
        return jnp.stack([V, alpha, beta, p + b[3], q + b[4], r + b[5], phi, th, psi,
                          qS * C["CX"] / af.mass + b[0], qS * C["CY"] / af.mass + b[1],
                          qS * C["CZ"] / af.mass + b[2]])

    return outputs


def run_child(kind: str, path: str, cache: str | None, extra_env: dict | None = None) -> dict:
    """One solver's cold and warm runs in a fresh process (``--child``), its JSON figures;
    ``cache`` the casest compile cache's folder, ``extra_env`` more environment variables."""
    env = {**os.environ, **(extra_env or {})}
    if cache:
        env["CASEST_CACHE_DIR"] = cache
    out = subprocess.run([sys.executable, os.path.abspath(__file__), "--child", kind, path], capture_output=True,
                         text=True, env=env)
    if out.returncode != 0:
        raise RuntimeError(f"the {kind} run failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_flight(skip_ipopt: bool = False, say=print) -> None:
    """The aircraft output error, every solver in a fresh process, in this run."""
    import casest

    folder = tempfile.mkdtemp(prefix="casest_bench_oe_")
    path = os.path.join(folder, "case.npz")
    make_case(path)
    model, data, start, _ = load_case(path)
    problem = casest.Problem(model, data)
    runs = {"casest Gauss-Newton": run_child("gauss-newton", path, os.path.join(folder, "cache_gn")),
            "casest Gauss-Newton, Gauss-Newton covariance": run_child("gauss-newton-gn-cov", path,
                                                                     os.path.join(folder, "cache_gn_cov"))}
    if not skip_ipopt:
        runs["casest IPOPT (exact Hessian)"] = run_child("ipopt", path, os.path.join(folder, "cache_ipopt"))
    try:
        runs["JAX + SciPy least_squares"] = run_child("jax", path, None)
    except RuntimeError as err:
        say(f"(JAX peer not run: {str(err).splitlines()[-1]})")
    say(f"Output error, 6-DOF aircraft (9 states, 38 parameters, 12 outputs), N = {data.n_samples}, R unknown (ML), "
        "from the two-step estimates; each solver in a fresh process (cold: empty compile cache / first jit), "
        "then again in that process (warm).")
    say()
    say("casest's times are whole estimates (stage 2 from the start, the covariance, the residual checks); "
        "by default the covariance is the inverse exact Hessian (the adjoint of the simulation over the first-order sensitivities), with "
        "`covariance='gauss-newton'` the inverse information from first-order sensitivities, as the peer would "
        "report it. The peer's times are the fit alone.")
    say()
    say("| solver | cold wall s | cold CPU s | warm wall s | ML cost reached | peak MiB | notes |")
    say("|---|---|---|---|---|---|---|")
    costs = {}
    for name, res in runs.items():
        cost = problem.profile_cost(res["cold"]["theta"])
        costs[name] = cost
        extra = (f"{res['cold']['jacobians']} Jacobians" if "jacobians" in res["cold"]
                 else f"{res['cold']['iterations']} iterations, success {res['cold']['success']}")
        say(f"| {name} | {res['cold']['wall']:.1f} | {res['cold']['cpu']:.1f} | {res['warm']['wall']:.1f} | "
            f"{cost:.12g} | {res['peak_mib']:.0f} | {extra} |")
    say()
    ref = costs["casest Gauss-Newton"]
    for name, cost in costs.items():
        say(f"- {name}: cost relative to Gauss-Newton's {abs(cost - ref) / abs(ref):.1e}; cold time / "
            f"Gauss-Newton's {runs[name]['cold']['wall'] / runs['casest Gauss-Newton']['cold']['wall']:.2f}")
    say()


def child_small(name: str, solver: str) -> dict:
    """A model file's default estimate (seed 0) twice in this fresh process: first and second run."""
    import casest
    from casest.backend.ipopt import SolverSettings

    mf = casest.load_model_file(os.path.join(HERE, "..", "..", "models", f"{name}.py"))
    model, data = mf.model(), mf.simulate(0)
    out = {}
    for label in ("cold", "warm"):
        t0 = time.perf_counter()
        est = casest.estimate(model, data, solver_settings=SolverSettings(output_error_solver=solver))
        out[label] = {"wall": time.perf_counter() - t0, "cost": float(est.cost), "success": bool(est.success)}
    return out


def bench_small(say=print) -> None:
    """The bundled dynamic model files: both stage-2 paths, each in a fresh process."""
    say("Whole estimates (stage 1, stage 2 from its starts, covariance) of the bundled dynamic model files, seed 0, "
        "each solver in a fresh process (first run, then a second run in that process):")
    say()
    say("| model | solver | first s | second s | cost | success |")
    say("|---|---|---|---|---|---|")
    for name in ("short_period", "data_compatibility"):
        costs = {}
        for solver in ("gauss-newton", "ipopt"):
            res = run_child(f"small:{name}:{solver}", "-", None)
            costs[solver] = res["cold"]["cost"]
            say(f"| {name} | {solver} | {res['cold']['wall']:.2f} | {res['warm']['wall']:.2f} | "
                f"{res['cold']['cost']:.12g} | {res['cold']['success']} |")
        say(f"| {name} | relative cost difference | | | {abs(costs['ipopt'] - costs['gauss-newton']) / abs(costs['ipopt']):.1e} | |")
    say()


def child_filter(formulation: str, solver: str, covariance: str) -> dict:
    """Filter-error ML on the longitudinal record (seed 0) twice in this fresh process."""
    import casest

    mf = casest.load_model_file(os.path.join(HERE, "..", "..", "models", "longitudinal.py"))
    model, data = mf.model(), mf.simulate(0)
    out = {}
    for label in ("cold", "warm"):
        t0 = time.perf_counter()
        fe = casest.filter_error_estimate(model, data, {"u": 0.1, "w": 0.1}, formulation=formulation, solver=solver,
                                          covariance=covariance)
        out[label] = {"wall": time.perf_counter() - t0, "cost": float(fe.cost), "success": bool(fe.success),
                      "iterations": int(fe.n_iterations)}
    return out


def bench_filter(say=print) -> None:
    """Filter-error ML in both formulations, both solvers, each in a fresh process."""
    say("Filter-error ML, `models/longitudinal.py` (4 states, 15 parameters, 2 gust intensities, 5 noise variances; "
        "600 samples with turbulence, seed 0); each configuration in a fresh process (first estimate, then a second "
        "in that process; the first includes building the graphs and, for the two forms that run the EKF at the "
        "optimum, the whiteness test's 19999 null draws). The innovation form runs Gauss-Newton (scoring) and "
        "reports the Cramer-Rao bounds; its V is N/2 ln det R + N n_y / 2 of the innovation covariance, not "
        "comparable with the other two:")
    say()
    say("| formulation | solver | covariance | first s | second s | second / first | second / innovation's second | "
        "iterations | V | success |")
    say("|---|---|---|---|---|---|---|---|---|---|")
    baseline = None
    for formulation in ("innovation", "steady-state", "time-varying"):
        configurations = ((("scoring", "fisher"),) if formulation == "innovation" else
                          (("scoring", "fisher"), ("scoring", "hessian"), ("ipopt", "hessian")))
        for solver, covariance in configurations:
            res = run_child(f"filter:{formulation}:{solver}:{covariance}", "-", None)
            baseline = baseline or res["warm"]["wall"]
            say(f"| {formulation} | {solver} | {covariance} | {res['cold']['wall']:.2f} | {res['warm']['wall']:.2f} | "
                f"{res['warm']['wall'] / res['cold']['wall']:.2f} | {res['warm']['wall'] / baseline:.2f} | "
                f"{res['cold']['iterations']} | {res['cold']['cost']:.10g} | {res['cold']['success']} |")
    say()


def bench_warm_spread(repeats: int, say=print) -> None:
    """Identical warm Gauss-Newton output-error estimates of the aircraft case, one after the other
    in this process (after a cold one): each call's wall and CPU seconds, and the spread (largest
    over smallest) of each."""
    import casest
    from casest.backend.ipopt import SolverSettings

    with tempfile.TemporaryDirectory(prefix="casest_oe_") as folder:
        path = os.path.join(folder, "case.npz")
        make_case(path)
        model, data, start, _ = load_case(path)
    settings = SolverSettings(output_error_solver="gauss-newton")
    walls, cpus = [], []
    for k in range(repeats + 1):
        t0, c0 = time.perf_counter(), time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            casest.estimate(model, data, start=dict(zip(model.parameter_names, start)), mode="full",
                            solver_settings=settings)
        if k:  # the first call is cold
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
    load = os.getloadavg()[0]
    say(f"Aircraft output error (Gauss-Newton), {repeats} identical warm calls in one process, load {load:.2f}:")
    say("")
    say("| | median s | smallest s | largest s | largest / smallest |")
    say("|---|---|---|---|---|")
    for label, values in (("wall", walls), ("CPU", cpus)):
        say(f"| {label} | {np.median(values):.3f} | {min(values):.3f} | {max(values):.3f} | "
            f"{max(values) / min(values):.2f} |")
    say("")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--skip-ipopt", action="store_true", help="leave out the IPOPT path (minutes)")
    parser.add_argument("--parts", nargs="+", default=["small", "aircraft", "filter"],
                        choices=["small", "aircraft", "filter", "spread"],
                        help="small: the bundled dynamic model files; aircraft: the 38-parameter output error; "
                             "filter: filter-error ML in both formulations; spread: identical warm aircraft calls")
    parser.add_argument("--repeats", type=int, default=7, help="warm calls of the spread part")
    parser.add_argument("--out", help="also write the table (Markdown) here")
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        kind, path = args.child
        if kind.startswith("small:"):
            _, name, solver = kind.split(":")
            result = child_small(name, solver)
        elif kind.startswith("filter:"):
            result = child_filter(*kind.split(":")[1:])
        else:
            result = child_jax(path) if kind == "jax" else child_casest(path, kind)
        print(json.dumps(result))
        return 0
    lines = []

    def say(text=""):
        print(text, flush=True)
        lines.append(text)

    if "small" in args.parts:
        bench_small(say)
    if "aircraft" in args.parts:
        bench_flight(args.skip_ipopt, say)
    if "filter" in args.parts:
        bench_filter(say)
    if "spread" in args.parts:
        bench_warm_spread(args.repeats, say)
    if args.out:
        from casest.data.dataset import atomic_write_text

        atomic_write_text(args.out, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
