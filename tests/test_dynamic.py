"""Dynamic models (states with an ODE): simulation, separation, stage 1, output-error stage 2.

Truths: (1) RK4 with substeps against CVODES at 1e-12 tolerance on a smooth linear
oscillator, to 1e-8; (2) the forward-sensitivity gradient and Hessian of the output-error
cost against CasADi's automatic differentiation through the simulation (1e-9 relative) and
the Hessian against central differences of that gradient (1e-5); (3) the output-error optimum
equals an independent fit written here with SciPy (solve_ivp at 1e-11 tolerance plus
least_squares, reweighted per channel until R settles) to 1e-5 relative; (4) simulated data
with fixed seeds: the estimate lies within 3 standard deviations of the truth.
"""

import os

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares

import casest
from casest.problem import output_error_sums

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TRUTH = {"a": 0.3, "k": 3.0, "c": 1.7, "d": -0.4}
NOISE = np.array([0.05, 0.02])


def oscillator(**options) -> casest.DynamicModel:
    """x'' = -k x - a x' + u; y1 = c x + d (a position sensor with scale and bias), y2 = x' (a rate)."""
    x, v, u, a, k, c, d = (ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "c", "d"))
    P = casest.Parameter
    return casest.DynamicModel(
        [P("a", 0.05, 2.0, 0.5), P("k", 0.5, 8.0, 2.0), P("c", -5.0, 5.0, 1.0), P("d", -5.0, 5.0, 0.0)],
        [casest.State("x", 0.0), casest.State("v", 0.0)], ["u"], {"x": v, "v": -k * x - a * v + u},
        {"y1": c * x + d, "y2": v}, name="oscillator", **options)


def oscillator_data(model, seed=0, n=1000, dt=0.02):
    t = np.arange(n) * dt
    u = np.sin(0.7 * t) + 0.5 * np.sin(2.3 * t) + 0.3 * np.cos(4.1 * t)
    zeros = np.zeros(n)
    _, clean = model.simulate(TRUTH, model.dataset({"t": t, "u": u, "y1": zeros, "y2": zeros}))
    z = clean + np.random.default_rng(seed).standard_normal(clean.shape) * NOISE
    return model.dataset({"t": t, "u": u, "y1": z[:, 0], "y2": z[:, 1]})


@pytest.mark.parametrize("hold", ["linear", "cubic", "zoh"])
def test_rk4_equals_cvodes_on_a_smooth_model(hold):
    rk4 = oscillator(substeps=4, input_hold=hold)
    cvodes = oscillator(integrator="cvodes", cvodes_tolerance=1e-12, input_hold=hold)
    data = oscillator_data(rk4)
    x_rk4, _ = rk4.simulate(TRUTH, data)
    x_cv, _ = cvodes.simulate(TRUTH, data)
    assert np.max(np.abs(x_rk4 - x_cv)) < 1e-8 * np.max(np.abs(x_cv))


def test_cubic_inputs_follow_a_smooth_input_closer():
    """Sampled sin(t): the states driven by the interpolated samples against the exact solution of
    x' = v, v' = -k x - a v + sin(t) (its steady part plus the decaying transient, solve_ivp at 1e-12)."""
    t = np.arange(400) * 0.05
    exact = solve_ivp(lambda tt, s: [s[1], -TRUTH["k"] * s[0] - TRUTH["a"] * s[1] + np.sin(tt)], (0, t[-1]), [0.0, 0.0],
                      t_eval=t, method="DOP853", rtol=1e-12, atol=1e-14).y.T
    errors = {}
    for hold in ("linear", "cubic"):
        model = oscillator(substeps=4, input_hold=hold)
        data = model.dataset({"t": t, "u": np.sin(t), "y1": 0 * t, "y2": 0 * t})
        errors[hold] = np.max(np.abs(model.simulate(TRUTH, data)[0] - exact))
    assert errors["cubic"] < errors["linear"] / 20, errors


@pytest.mark.parametrize("n_samples", [2, 3, 4, 50])
def test_numeric_interval_inputs_equal_the_graphs(n_samples):
    """The interval inputs the compiled passes read (NumPy) are those of the graph (the cubic hold's
    neighbours, the record's ends extrapolated linearly), to the bit."""
    model = oscillator(input_hold="cubic")
    U = np.random.default_rng(n_samples).standard_normal((n_samples, 1))
    a, b = model.interval_input_values(U)
    Um = ca.MX.sym("u", 1, n_samples)
    A, B = ca.Function("interval_inputs", [Um], list(model.interval_inputs(Um)))(U.T)
    np.testing.assert_array_equal(a, np.asarray(A).T)
    np.testing.assert_array_equal(b, np.asarray(B).T)


def test_split_puts_the_dynamics_in_xi2():
    part = casest.separate(oscillator())
    assert part.linear == ("c", "d") and part.nonlinear == ("a", "k")
    with pytest.raises(casest.SeparationError, match="rhs or the initial state"):
        casest.separate(oscillator(), linear=["a"])


def test_sensitivity_derivatives_equal_automatic_differentiation_and_differences():
    model = oscillator()
    data = oscillator_data(model, n=400)
    problem = casest.Problem(model, data)
    N = data.n_samples
    sums = output_error_sums(model, N, model.scales)
    w = np.concatenate([model.vector(TRUTH) * 1.05 / model.scales, np.log([0.003, 0.0005])])
    p = problem.data_vector()
    ws, ps = ca.MX.sym("w", w.size), ca.MX.sym("p", p.size)
    J = problem.cost_expression(ws[:4] * ca.DM(model.scales), ws[4:], ps) / N
    J_ad, g_ad, H_ad = (np.asarray(v) for v in ca.Function("ad", [ws, ps], [J, ca.gradient(J, ws),
                                                                             ca.hessian(J, ws)[0]])(w, p))
    f, g = (np.asarray(v) for v in sums.gradient(w, p))
    H = np.asarray(ca.densify(sums.hessian(w, p)))
    H = H + H.T - np.diag(np.diag(H))
    assert f.item() == pytest.approx(J_ad.item(), rel=1e-12)
    np.testing.assert_allclose(g.ravel(), g_ad.ravel(), rtol=1e-9, atol=1e-9 * np.abs(g_ad).max())
    np.testing.assert_allclose(H, H_ad, rtol=1e-9, atol=1e-9 * np.abs(H_ad).max())
    step = 1e-6
    H_fd = np.column_stack([(np.asarray(sums.gradient(w + step * e, p)[1]) - np.asarray(sums.gradient(w - step * e, p)[1]))
                            .ravel() / (2 * step) for e in np.eye(w.size)])
    np.testing.assert_allclose(H, H_fd, rtol=1e-5, atol=1e-6 * np.abs(H).max())


def test_output_error_equals_a_scipy_fit():
    """SciPy: solve_ivp (DOP853, 1e-12, interval by interval, where the linearly interpolated input is
    smooth) of the states and their sensitivities to a and k, least_squares with that exact Jacobian,
    R re-estimated from the residuals until it settles (the ML fixed point)."""
    model = oscillator(substeps=4)
    data = oscillator_data(model, seed=1, n=200)
    est = casest.estimate(model, data)
    assert est.success
    t, u, z = data.signals[:, 0], data.signals[:, 1], data.outputs

    def simulate(theta):
        a, k = theta[0], theta[1]
        s, out = np.zeros(6), [np.zeros(6)]
        for i in range(t.size - 1):
            slope = (u[i + 1] - u[i]) / (t[i + 1] - t[i])

            def rhs(tt, s, i=i, slope=slope):  # x, v and their derivatives with respect to a and k
                x, v, xa, va, xk, vk = s
                return [v, -k * x - a * v + u[i] + slope * (tt - t[i]), va, -k * xa - v - a * va, vk, -x - k * xk - a * vk]

            s = solve_ivp(rhs, (t[i], t[i + 1]), s, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
            out.append(s)
        return np.array(out).T

    def residuals(theta, R):
        x, v = simulate(theta)[:2]
        return ((z - np.column_stack([theta[2] * x + theta[3], v])) / np.sqrt(R)).ravel()

    def jacobian(theta, R):
        x, v, xa, va, xk, vk = simulate(theta)
        c = theta[2]
        J = np.zeros((t.size, 2, 4))
        J[:, 0] = np.column_stack([c * xa, c * xk, x, np.ones_like(x)])
        J[:, 1] = np.column_stack([va, vk, np.zeros_like(x), np.zeros_like(x)])
        return -(J / np.sqrt(R)[None, :, None]).reshape(-1, 4)

    theta, R = model.nominal.copy(), np.var(z, axis=0)
    for _ in range(50):  # ML with unknown R: weighted least squares, then R from the residuals
        theta = least_squares(residuals, theta, jac=jacobian, args=(R,), bounds=(model.lower_bounds, model.upper_bounds),
                              x_scale=model.scales, xtol=1e-13, ftol=1e-13, gtol=1e-13).x
        R_new = R * np.mean(residuals(theta, R).reshape(-1, 2) ** 2, axis=0)
        settled = np.all(np.abs(R_new - R) < 1e-10 * R)
        R = R_new
        if settled:
            break
    np.testing.assert_allclose(est.theta, theta, rtol=1e-5)
    np.testing.assert_allclose(est.R, R, rtol=1e-5)


@pytest.mark.parametrize("seed", [2, 3])
def test_oscillator_estimate_within_three_std(seed):
    model = oscillator()
    est = casest.estimate(model, oscillator_data(model, seed=seed))
    assert est.success and est.landscape.verdict == "unique"
    truth = model.vector(TRUTH)
    assert np.all(np.abs(est.theta - truth) < 3 * est.std), (est.theta - truth) / est.std
    np.testing.assert_allclose(np.sqrt(est.R), NOISE, rtol=0.1)


@pytest.mark.parametrize("missing, jit", [(False, False), (True, True)])
def test_stage1_sums_equal_least_squares_on_the_simulated_outputs(missing, jit):
    # truth: for each xi2 = (a, k) the model is simulated (DynamicModel.simulate) and xi1 =
    # (c, d) fitted by numpy.linalg.lstsq on the measured samples of each channel
    model = oscillator()
    data = oscillator_data(model, seed=6, n=301)  # an odd N with a last sample after the recursion
    if missing:
        y1 = data.outputs[:, 0].copy()
        y1[np.random.default_rng(7).random(y1.size) < 0.3] = np.nan
        data = model.dataset({"t": data.signals[:, 0], "u": data.signals[:, 1], "y1": y1, "y2": data.outputs[:, 1]},
                             missing="allow")
    cands = np.array([[0.3, 3.0], [0.1, 1.0], [1.5, 6.5]])
    land = casest.sweep(model, data, candidates=cands, settings=casest.SweepSettings(jit=jit, threads=1))
    for m, (a, k) in enumerate(cands):
        _, clean = model.simulate({"a": a, "k": k, "c": 1.0, "d": 0.0}, data)
        seen = np.isfinite(data.outputs[:, 0])
        A = np.column_stack([clean[seen, 0], np.ones(seen.sum())])
        xi1, *_ = np.linalg.lstsq(A, data.outputs[seen, 0], rcond=None)
        r1 = np.mean((data.outputs[seen, 0] - A @ xi1) ** 2)
        r2 = np.mean((data.outputs[:, 1] - clean[:, 1]) ** 2)
        np.testing.assert_allclose(land.xi1[m], xi1, rtol=1e-8)
        np.testing.assert_allclose(land.R[m], [r1, r2], rtol=1e-8)


def test_missing_outputs_of_a_dynamic_model():
    model = oscillator()
    data = oscillator_data(model, seed=4)
    y2 = data.outputs[:, 1].copy()
    y2[np.random.default_rng(5).random(y2.size) < 0.4] = np.nan
    gappy = model.dataset({"t": data.signals[:, 0], "u": data.signals[:, 1], "y1": data.outputs[:, 0], "y2": y2},
                          missing="allow")
    est = casest.estimate(model, gappy)
    assert est.success
    truth = model.vector(TRUTH)
    assert np.all(np.abs(est.theta - truth) < 3 * est.std)
    assert est.n_measured == data.n_samples + np.isfinite(y2).sum()


def test_bad_time_column_and_static_integrator_are_refused():
    model = oscillator()
    data = oscillator_data(model, n=50)
    columns = {"t": data.signals[::-1, 0], "u": data.signals[:, 1], "y1": data.outputs[:, 0], "y2": data.outputs[:, 1]}
    with pytest.raises(casest.DataError, match="must increase strictly"):
        casest.estimate(model, model.dataset(columns))
    x, k = ca.MX.sym("x"), ca.MX.sym("k")
    F = ca.integrator("F", "cvodes", {"x": x, "p": k, "ode": -k * x}, 0.0, 1.0)
    with pytest.raises(casest.ModelError, match="DynamicModel"):
        casest.Model([casest.Parameter("k", 0.0, 5.0, 1.0)], ["u"], {"y": F(x0=ca.MX.sym("u"), p=k)["xf"]})


def test_data_compatibility_with_the_ode_within_three_std():
    """Paper Appendix B.B in full: the IMU biases through Eq. B5, the output errors of Eq. B6."""
    dc = casest.load_model_file(os.path.join(REPO, "models", "data_compatibility.py"))
    model = dc.model()
    est = casest.estimate(model, dc.simulate(0))
    assert est.success
    truth = model.vector(dc.TRUTH)
    assert np.all(np.abs(est.theta - truth) < 3 * est.std), (est.theta - truth) / est.std


def test_short_period_output_error_within_three_std():
    """The second dynamic example: stability and control derivatives swept, sensor biases linear."""
    sp = casest.load_model_file(os.path.join(REPO, "models", "short_period.py"))
    model, data = sp.model(), sp.simulate(1)
    part = casest.separate(model)
    assert set(part.linear) == {"b_alpha", "b_q"}
    est = casest.estimate(model, data)
    assert est.success and est.landscape.verdict == "unique"
    truth = model.vector(sp.TRUTH)
    assert np.all(np.abs(est.theta - truth) < 3 * est.std), (est.theta - truth) / est.std
    guess = casest.estimate(model, data, start=sp.SINGLE_STAGE_START, mode="full")
    assert guess.cost == pytest.approx(est.cost, rel=1e-9)


def test_estimated_initial_state():
    """x(t_0) as a parameter (in xi2): recovered within 3 std from a record that starts displaced."""
    x, v, u, a, k, c, d, x0 = (ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "c", "d", "x0"))
    P = casest.Parameter
    model = casest.DynamicModel(
        [P("a", 0.05, 2.0, 0.5), P("k", 0.5, 8.0, 2.0), P("c", -5.0, 5.0, 1.0), P("d", -5.0, 5.0, 0.0),
         P("x0", -2.0, 2.0, 0.0)],
        [casest.State("x", "x0"), casest.State("v", 0.0)], ["u"], {"x": v, "v": -k * x - a * v + u},
        {"y1": c * x + d, "y2": v}, substeps=2)
    assert "x0" in casest.separate(model).nonlinear
    truth = dict(TRUTH, x0=0.8)
    t = np.arange(800) * 0.02
    u = np.sin(0.7 * t) + 0.5 * np.sin(2.3 * t)
    zeros = np.zeros_like(t)
    _, clean = model.simulate(truth, model.dataset({"t": t, "u": u, "y1": zeros, "y2": zeros}))
    z = clean + np.random.default_rng(6).standard_normal(clean.shape) * NOISE
    est = casest.estimate(model, model.dataset({"t": t, "u": u, "y1": z[:, 0], "y2": z[:, 1]}))
    assert est.success
    assert np.all(np.abs(est.theta - model.vector(truth)) < 3 * est.std)


@pytest.mark.parametrize("noise", ["known", "correlated"])
def test_noise_models_of_the_problem_layer(noise):
    """Known R (weighted least squares, std from the given R) and a full unknown R, through the ODE."""
    model = oscillator()
    data = oscillator_data(model, seed=7)
    option = casest.KnownNoise({"y1": 0.05, "y2": 0.02}) if noise == "known" else casest.CorrelatedNoise()
    est = casest.estimate(model, data, noise=option)
    assert est.success
    truth = model.vector(TRUTH)
    assert np.all(np.abs(est.theta - truth) < 3 * est.std), (est.theta - truth) / est.std
    if noise == "known":
        np.testing.assert_allclose(est.R, [0.05**2, 0.02**2])
    else:  # the ML full R is the residual covariance at the estimate
        resid = data.outputs - model.predict_data(est.theta, data)
        np.testing.assert_allclose(est.R_full, resid.T @ resid / data.n_samples, rtol=1e-6, atol=1e-12)


def test_multiple_shooting_reaches_the_single_shooting_optimum():
    """State nodes every 150 samples with continuity constraints: the same optimum and std (1e-7)."""
    model = oscillator()
    data = oscillator_data(model, seed=8)
    single = casest.estimate(model, data)
    multiple = casest.estimate(model, data, solver_settings=casest.SolverSettings(shooting="multiple",
                                                                                 shooting_interval=150))
    assert single.success and multiple.success
    np.testing.assert_allclose(multiple.theta, single.theta, rtol=1e-7)
    np.testing.assert_allclose(multiple.std, single.std, rtol=1e-7)
    assert multiple.cost == pytest.approx(single.cost, rel=1e-10)
    with pytest.raises(casest.OptionError, match="shooting"):
        casest.SolverSettings(shooting="triple")
