#!/usr/bin/env python3
"""The EKF and the UKF over a long record: casest's compiled passes against filterpy (and a JAX
``lax.scan`` EKF).

    python3 scripts/benchmarks/bench_filters.py [--n 10000] [--repeats 3]

The pendulum of the state-estimation tutorial (docs/tutorials/state-estimation.md; 2 states, 2 outputs, RK4 with 4 substeps, zero-order hold), N samples,
every measurement present. All three filters get the same information: the RK4 step with its
Jacobian, the trapezoidal discrete Q, the Joseph update; filterpy's ``ExtendedKalmanFilter``
with the step and its Jacobian (the tangent through the RK4 stages), h and H written by hand
in NumPy; JAX with the same RK4 written in ``jax.numpy``,
``jax.jacfwd`` for Phi and H, the whole pass in one ``jax.lax.scan`` under ``jit`` (float64).
Timed in the same process: casest cold (the first pass: building and compiling the step; with
an empty compile cache if ``--cold-cache``) and warm (the next record); JAX with its compile
apart; filterpy as it runs; with numba installed, the same EKF as a plain loop over scalars
compiled by numba (``ekf_numba_peer.py``, written for this model only: what the recursion
itself costs). Each result is checked against casest's (max |x| difference).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casadi as ca  # noqa: E402

import casest  # noqa: E402
from casest.filters.ekf import ExtendedKalmanFilter  # noqa: E402

from filter_case import DT, G, SUBSTEPS  # noqa: E402  (the pendulum's constants, shared with the numba peer)
THETA = {"c": 0.3, "L": 1.0}
Q_RATE, R_VAR, P0 = 0.5, 0.05**2, np.eye(2) * 1e-4


def pendulum() -> casest.DynamicModel:
    ang, rate, torque, c, L = (ca.SX.sym(n) for n in ("ang", "rate", "torque", "c", "L"))
    P = casest.Parameter
    return casest.DynamicModel(
        [P("c", 0.0, 2.0, 0.3), P("L", 0.5, 2.0, 1.0)], [casest.State("ang", 1.0), casest.State("rate", 0.0)],
        ["torque"], rhs={"ang": rate, "rate": -G / L * ca.sin(ang) - c * rate + torque},
        outputs={"px": L * ca.sin(ang), "py": -L * ca.cos(ang)}, substeps=SUBSTEPS, input_hold="zoh")


def record(model, N: int, seed: int) -> casest.Dataset:
    rng = np.random.default_rng(seed)
    t = np.arange(N) * DT
    torque = 0.5 * np.sin(1.3 * t) + 0.2 * rng.standard_normal(N)
    _, Y = model.simulate(THETA, model.dataset({"t": t, "torque": torque, "px": 0 * t, "py": 0 * t}))
    Y = Y + rng.normal(0.0, 0.05, Y.shape)
    return model.dataset({"t": t, "torque": torque, "px": Y[:, 0], "py": Y[:, 1]})


def _rk4_numpy(x, u, c, L):
    """The RK4 step and its Jacobian Phi (the tangent propagated through the stages, by hand)."""
    def f(s, T):
        A = np.array([[0.0, 1.0], [-G / L * np.cos(s[0]), -c]])
        return np.array([s[1], -G / L * np.sin(s[0]) - c * s[1] + u]), A @ T

    h = DT / SUBSTEPS
    T = np.eye(2)
    for _ in range(SUBSTEPS):
        k1, j1 = f(x, T)
        k2, j2 = f(x + h / 2 * k1, T + h / 2 * j1)
        k3, j3 = f(x + h / 2 * k2, T + h / 2 * j2)
        k4, j4 = f(x + h * k3, T + h * j3)
        x, T = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), T + h / 6 * (j1 + 2 * j2 + 2 * j3 + j4)
    return x, T


def filterpy_pass(data: casest.Dataset) -> np.ndarray:
    """filterpy's EKF with the RK4 step, its Jacobian and h, H written in NumPy."""
    from filterpy.kalman import ExtendedKalmanFilter as FilterpyEKF

    c, L = THETA["c"], THETA["L"]
    Qc = np.diag([0.0, Q_RATE])
    kf = FilterpyEKF(dim_x=2, dim_z=2)
    kf.x, kf.P, kf.R = np.array([1.0, 0.0]), P0.copy(), np.eye(2) * R_VAR
    U, Y = data.signals[:, 1], data.outputs
    out = np.empty((data.n_samples, 2))

    def hx(x):
        return np.array([L * np.sin(x[0]), -L * np.cos(x[0])])

    def jac(x):
        return np.array([[L * np.cos(x[0]), 0.0], [L * np.sin(x[0]), 0.0]])

    for k in range(data.n_samples):
        kf.update(Y[k], jac, hx)
        out[k] = kf.x
        if k < data.n_samples - 1:
            x_next, Phi = _rk4_numpy(kf.x, U[k], c, L)
            kf.F = Phi
            kf.Q = 0.5 * DT * (Phi @ Qc @ Phi.T + Qc)
            kf.predict_x = lambda u=0, x_next=x_next: setattr(kf, "x", x_next)
            kf.predict()
    return out


def jax_pass_factory():
    """A jitted EKF over a record: RK4 in jax.numpy, jacfwd for Phi and H, lax.scan over the samples."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    c, L = THETA["c"], THETA["L"]
    Qc, R = jnp.diag(jnp.array([0.0, Q_RATE])), jnp.eye(2) * R_VAR

    def step(x, u):
        def f(s):
            return jnp.array([s[1], -G / L * jnp.sin(s[0]) - c * s[1] + u])

        h = DT / SUBSTEPS
        for _ in range(SUBSTEPS):
            k1 = f(x)
            k2 = f(x + h / 2 * k1)
            k3 = f(x + h / 2 * k2)
            k4 = f(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return x

    def measure(x):
        return jnp.array([L * jnp.sin(x[0]), -L * jnp.cos(x[0])])

    def sample(carry, inputs):
        x, P = carry
        y, u = inputs
        H = jax.jacfwd(measure)(x)
        S = H @ P @ H.T + R
        K = jnp.linalg.solve(S, H @ P).T
        x = x + K @ (y - measure(x))
        I_KH = jnp.eye(2) - K @ H
        P = I_KH @ P @ I_KH.T + K @ R @ K.T
        Phi = jax.jacfwd(step)(x, u)
        x_next = step(x, u)
        P_next = Phi @ P @ Phi.T + 0.5 * DT * (Phi @ Qc @ Phi.T + Qc)
        return (x_next, 0.5 * (P_next + P_next.T)), x

    @jax.jit
    def run(Y, U):
        _, xs = jax.lax.scan(sample, (jnp.array([1.0, 0.0]), jnp.asarray(P0)), (Y, U))
        return xs

    return run


def filterpy_ukf_pass(data: casest.Dataset, alpha: float, beta: float, kappa: float) -> np.ndarray:
    """filterpy's UnscentedKalmanFilter (Merwe's sigma points) with the RK4 step and h in NumPy."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter as FilterpyUKF

    c, L = THETA["c"], THETA["L"]
    points = MerweScaledSigmaPoints(2, alpha=alpha, beta=beta, kappa=kappa)
    ukf = FilterpyUKF(dim_x=2, dim_z=2, dt=DT, hx=lambda x: np.array([L * np.sin(x[0]), -L * np.cos(x[0])]),
                      fx=None, points=points)
    ukf.x, ukf.P, ukf.R, ukf.Q = np.array([1.0, 0.0]), P0.copy(), np.eye(2) * R_VAR, np.diag([0.0, Q_RATE]) * DT
    ukf.sigmas_f = points.sigma_points(ukf.x, ukf.P)
    U, Y = data.signals[:, 1], data.outputs
    out = np.empty((data.n_samples, 2))
    for k in range(data.n_samples):
        ukf.update(Y[k])
        out[k] = ukf.x
        if k < data.n_samples - 1:
            ukf.predict(fx=lambda x, dt, u=U[k]: _rk4_numpy(x, u, c, L)[0])
    return out


def bench_ukf(N: int, repeats: int, say=print) -> dict:
    """The unscented filter: casest's compiled pass (cold, warm), its Python loop, filterpy's UKF."""
    from casest.filters import UnscentedKalmanFilter

    model = pendulum()
    first, second = record(model, N, 1), record(model, N, 2)
    alpha, beta, kappa = 0.5, 2.0, 1.0
    ukf = UnscentedKalmanFilter(model, THETA, {"rate": Q_RATE}, [R_VAR] * 2, P0, alpha=alpha, beta=beta, kappa=kappa)
    t_cold, ours_first = timed(ukf.filter, first)
    warm = [timed(ukf.filter, second) for _ in range(repeats)]
    t_warm, ours = min(w[0] for w in warm), warm[0][1].x_filtered
    t_loop, loop = timed(lambda d: ukf.filter(d, compiled=False), second)
    t_filterpy, fp = timed(filterpy_ukf_pass, second, alpha, beta, kappa)
    say(f"UKF over the pendulum record, N = {N} samples, alpha {alpha}, beta {beta}, kappa {kappa} "
        "(time in s; ratio: time / casest warm):")
    say()
    say("| filter | time s | / casest warm | max abs x difference to casest |")
    say("|---|---|---|---|")
    for name, t, x in (("casest UKF, one CasADi pass (cold: build + run)", t_cold, ours_first.x_filtered),
                       ("casest UKF, one CasADi pass (warm, best of %d)" % repeats, t_warm, ours),
                       ("casest UKF, step by step (Python loop)", t_loop, loop.x_filtered),
                       ("filterpy UnscentedKalmanFilter", t_filterpy, fp)):
        ref = ours_first.x_filtered if "cold" in name else ours
        say(f"| {name} | {t:.4f} | {t / t_warm:.3g} | {np.max(np.abs(x - ref)):.1e} |")
    say()
    return {"ukf_cold": t_cold, "ukf_warm": t_warm, "ukf_loop": t_loop, "ukf_filterpy": t_filterpy}


def timed(fun, *args):
    t0 = time.perf_counter()
    out = fun(*args)
    return time.perf_counter() - t0, out


def bench(N: int, repeats: int, say=print) -> dict:
    import ekf_numba_peer

    model = pendulum()
    first, second = record(model, N, 1), record(model, N, 2)
    ekf = ExtendedKalmanFilter(model, THETA, {"rate": Q_RATE}, [R_VAR] * 2, P0)
    t_cold, ours_first = timed(ekf.filter, first)
    Yj, Uj = second.outputs, second.signals[:, 1]
    times, loop_pass = {}, None
    if ekf_numba_peer.available():  # the recursion as a plain compiled loop (written for this model only)
        loop_pass = ekf_numba_peer.ekf_pass_factory()
        arguments = (np.ascontiguousarray(Yj), np.ascontiguousarray(Uj), THETA["c"], THETA["L"], Q_RATE, R_VAR,
                     float(P0[0, 0]))
        times["numba_first"], xn = timed(loop_pass, *arguments)
    # warm casest and the numba loop interleaved, best of the repeats each; casest once with its
    # results kept (each run then writes fresh memory) and once with them freed at once, as the
    # peer's are
    warm, freed, numba_runs = [], [], []
    for keep in (True, False):
        for _ in range(repeats):
            if keep:
                warm.append(timed(ekf.filter, second))
            else:
                freed.append(timed(ekf.filter, second)[0])
            if loop_pass is not None:
                numba_runs.append(timed(loop_pass, *arguments)[0])
    t_warm, ours = min(w[0] for w in warm), warm[0][1].x_filtered
    times["casest_freed"] = min(freed)
    t_loop, loop = timed(lambda d: ekf.filter(d, compiled=False), second)
    t_filterpy, fp = timed(filterpy_pass, second)
    run = jax_pass_factory()
    t_jax_first, xj = timed(lambda: np.asarray(run(Yj, Uj)))
    t_jax = min(timed(lambda: np.asarray(run(Yj, Uj)))[0] for _ in range(repeats))
    rows = [("casest, compiled pass (cold: build + compile + run)", t_cold, ours_first.x_filtered, None),
            ("casest, compiled pass (warm, best of %d, results kept)" % repeats, t_warm, ours, None),
            ("casest, compiled pass (warm, best of %d, results freed at once as the numba peer's)" % repeats,
             times["casest_freed"], ours, None),
            ("casest, step by step (Python loop)", t_loop, loop.x_filtered, None),
            ("filterpy ExtendedKalmanFilter", t_filterpy, fp, None),
            ("JAX lax.scan EKF (first call: trace + compile + run)", t_jax_first, xj, None),
            ("JAX lax.scan EKF (compiled, best of %d)" % repeats, t_jax, xj, None)]
    if loop_pass is not None:
        times["numba"] = min(numba_runs)
        rows += [("numba loop EKF (first call: compile + run)", times["numba_first"], xn, None),
                 ("numba loop EKF (compiled, best of %d, interleaved with casest warm)" % repeats, times["numba"], xn,
                  None)]
    say(f"EKF over the pendulum record, N = {N} samples (time in s; ratio: time / casest warm):")
    say()
    say("| filter | time s | / casest warm | max abs x difference to casest |")
    say("|---|---|---|---|")
    for name, t, x, _ in rows:
        ref = ours_first.x_filtered if "cold" in name else ours
        say(f"| {name} | {t:.4f} | {t / t_warm:.3g} | {np.max(np.abs(x - ref)):.1e} |")
    say()
    if "numba" in times:
        say(f"casest warm / numba loop: {t_warm / times['numba']:.2f} with casest's results kept (each run writes "
            f"fresh memory), {times['casest_freed'] / times['numba']:.2f} with them freed at once as the peer's.")
        say()
    return {"casest_cold": t_cold, "casest_warm": t_warm, "loop": t_loop, "filterpy": t_filterpy,
            "jax_first": t_jax_first, "jax": t_jax, **times}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=10000, help="samples in the record")
    parser.add_argument("--repeats", type=int, default=7, help="warm repeats (the best is reported)")
    parser.add_argument("--cold-cache", action="store_true",
                        help="an empty compile cache, so the cold casest figure includes the C compile")
    args = parser.parse_args(argv)
    if args.cold_cache:
        import tempfile

        os.environ["CASEST_CACHE_DIR"] = tempfile.mkdtemp(prefix="casest_bench_cache_")
    bench(args.n, args.repeats)
    bench_ukf(args.n, args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
