"""Features that cross the static/dynamic border: fixed parameters, the embedding API,
several manoeuvres of a dynamic model.

Truths: a DynamicModel with a parameter held equals the same model written by hand with
the value in its equations (estimates to 1e-8); the embedding API's optimum of a dynamic
problem equals ``casest.estimate``'s (same ML cost, paper Eq. 6, to 1e-8 relative); two
manoeuvres with their own initial states equal one joint NLP written here by hand in CasADi
(cost to 1e-8); stacked manoeuvres simulate as each one alone (1e-12); simulated truth
within 3 std.
"""

import casadi as ca
import numpy as np
import pytest

import casest

TRUTH = {"a": 0.3, "k": 3.0, "c": 1.7, "d": -0.4, "x0": 0.6}
NOISE = np.array([0.05, 0.02])


def oscillator(held: dict | None = None) -> casest.DynamicModel:
    """x'' = -k x - a x' + u, x(0) = x0; y1 = c x + d, y2 = x'. ``held``: written in as numbers."""
    held = held or {}
    s = {n: ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "c", "d", "x0")}
    value = {n: held.get(n, s[n]) for n in ("a", "k", "c", "d")}
    P = casest.Parameter
    params = [P("a", 0.05, 2.0, 0.5), P("k", 0.5, 8.0, 2.0), P("c", -5.0, 5.0, 1.0), P("d", -5.0, 5.0, 0.0),
              P("x0", -2.0, 2.0, 0.0)]
    return casest.DynamicModel(
        [p for p in params if p.name not in held],
        [casest.State("x", held.get("x0", "x0")), casest.State("v", 0.0)], ["u"],
        {"x": s["v"], "v": -value["k"] * s["x"] - value["a"] * s["v"] + s["u"]},
        {"y1": value["c"] * s["x"] + value["d"], "y2": s["v"]}, name="oscillator", substeps=2)


@pytest.fixture(scope="module")
def record():
    model = oscillator()
    t = np.arange(600) * 0.02
    u = np.sin(0.7 * t) + 0.5 * np.sin(2.3 * t)
    zeros = np.zeros_like(t)
    _, clean = model.simulate(TRUTH, model.dataset({"t": t, "u": u, "y1": zeros, "y2": zeros}))
    z = clean + np.random.default_rng(11).standard_normal(clean.shape) * NOISE
    return model, model.dataset({"t": t, "u": u, "y1": z[:, 0], "y2": z[:, 1]})


@pytest.mark.parametrize("held", [{"d": -0.4}, {"k": 3.0, "x0": 0.6}])
def test_dynamic_model_with_fixed_parameters_equals_the_model_written_with_the_values(record, held):
    model, data = record
    by_hand = oscillator(held)
    reference = casest.estimate(by_hand, by_hand.dataset({n: data.column(n) for n in ("t", "u", "y1", "y2")}))
    est = casest.estimate(model, data, fixed=held)
    assert est.success and reference.success
    for name in by_hand.parameter_names:
        np.testing.assert_allclose(est.values[name], reference.values[name], rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(est.stds[name], reference.stds[name], rtol=1e-6)
    for name, value in held.items():
        assert est.values[name] == value and est.stds[name] is None
    assert est.fixed_parameters == tuple(held)
    np.testing.assert_allclose(est.cost, reference.cost, rtol=1e-10)


@pytest.fixture(scope="module")
def reference(record):
    model, data = record
    est = casest.estimate(model, data)
    assert est.success
    return est


def test_add_to_opti_with_a_dynamic_model_reaches_the_estimate(record, reference):
    from casest.interop import add_to_opti

    model, data = record
    opti = ca.Opti()
    est = add_to_opti(opti, model, data, start="stage1")
    est.minimize()
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes"})
    theta, R = est.values(opti.solve())
    problem = casest.Problem(model, data)
    np.testing.assert_allclose(problem.cost(theta, R), reference.cost, rtol=1e-8)
    np.testing.assert_allclose(theta, reference.theta, rtol=1e-5, atol=1e-7)
    unc = est.standard_deviations(opti.debug)
    np.testing.assert_allclose(unc.std, reference.std, rtol=1e-4)


def test_ml_problem_of_a_dynamic_model_reaches_the_estimate(record, reference):
    from casest.interop import ml_problem

    model, data = record
    ml = ml_problem(casest.Problem(model, data))
    solver = ml.solver()
    lbx, ubx = ml.bounds()
    sol = solver(x0=ml.x0(reference.theta * 1.02, reference.R * 1.5), p=ml.data_vector(), lbx=lbx, ubx=ubx)
    theta, R = ml.unpack(sol["x"])
    np.testing.assert_allclose(float(sol["f"]) * ml.n_samples, reference.cost, rtol=1e-8)
    np.testing.assert_allclose(theta, reference.theta, rtol=1e-5, atol=1e-7)
    with pytest.raises(casest.OptionError, match="build the problem from casest.Problem"):
        ml_problem(model, data.n_samples)


@pytest.mark.parametrize("noise", [None, casest.CorrelatedNoise()])
def test_estimator_function_of_a_dynamic_problem_reaches_the_estimate(record, noise):
    from casest.interop import estimator_function

    model, data = record
    problem = casest.Problem(model, data, noise=noise)
    reference = casest.estimate(problem)
    F = estimator_function(problem)
    theta, R = F(problem.data_vector(), reference.theta * 1.01)
    theta = np.asarray(theta).reshape(-1)
    np.testing.assert_allclose(problem.cost(theta, np.asarray(R) if noise else np.asarray(R).reshape(-1)),
                               reference.cost, rtol=1e-8)
    np.testing.assert_allclose(theta, reference.theta, rtol=1e-5, atol=1e-7)


def test_estimator_function_of_a_static_problem_with_fixed_parameters(record):
    """The Problem route on a static model with a fixed parameter and known noise equals estimate()."""
    from casest.interop import estimator_function

    scalar2 = casest.load_model_file("scalar2")
    model, data = scalar2.model(), scalar2.simulate(0)
    problem = casest.Problem(model, data, fixed={"d": 0.0}, noise=casest.KnownNoise({"z": 0.3}))
    reference = casest.estimate(problem)
    theta, R = estimator_function(problem)(problem.data_vector(), problem.vector(reference.theta) + 0.01)
    np.testing.assert_allclose(np.asarray(theta).reshape(-1), problem.vector(reference.theta), rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(np.asarray(R).reshape(-1), [0.09], rtol=1e-12)


# ----------------------------------------------------------------------------- dynamic experiments
def _manoeuvre(seed: int, x0: float, n: int, shift: float = 0.0) -> dict:
    """Columns of one simulated manoeuvre from x(t0) = x0 (and the state column ``x`` holding x0)."""
    t = np.arange(n) * 0.02 + shift
    u = np.sin(0.7 * t + seed) + 0.5 * np.sin(2.3 * t)
    zeros = np.zeros_like(t)
    _, clean = oscillator().simulate({**TRUTH, "x0": x0}, oscillator().dataset({"t": t, "u": u, "y1": zeros,
                                                                                 "y2": zeros}))
    z = clean + np.random.default_rng(seed).standard_normal(clean.shape) * NOISE
    return {"t": t, "u": u, "y1": z[:, 0], "y2": z[:, 1], "x": np.full(n, x0)}


def _hand_written_joint_nlp(manoeuvres: list) -> tuple:
    """The ML problem of several manoeuvres written here in CasADi: RK4 with two substeps and
    linear input interpolation per manoeuvre, each from its own x0, one R per manoeuvre and output."""
    a, k, c, d = (ca.MX.sym(n) for n in "akcd")
    x0s = [ca.MX.sym(f"x0_{i}") for i in range(len(manoeuvres))]
    rhos = [ca.MX.sym(f"rho_{i}", 2) for i in range(len(manoeuvres))]

    def ode(state, u, a_, k_):
        return ca.vertcat(state[1], -k_ * state[0] - a_ * state[1] + u)

    J = 0
    for m, x0, rho in zip(manoeuvres, x0s, rhos):
        t, u = m["t"], m["u"]
        state, residuals = ca.vertcat(x0, 0), []
        for i in range(len(t)):
            residuals.append(ca.vertcat(m["y1"][i] - (c * state[0] + d), m["y2"][i] - state[1]))
            if i + 1 == len(t):
                break
            dt = t[i + 1] - t[i]
            for j in range(2):
                h = dt / 2
                ua, um, ub = (u[i] + s * (u[i + 1] - u[i]) for s in (j / 2, (j + 0.5) / 2, (j + 1) / 2))
                k1 = ode(state, ua, a, k)
                k2 = ode(state + 0.5 * h * k1, um, a, k)
                k3 = ode(state + 0.5 * h * k2, um, a, k)
                k4 = ode(state + h * k3, ub, a, k)
                state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        r = ca.horzcat(*residuals)
        J = J + 0.5 * ca.sum1(ca.sum2(r**2) / ca.exp(rho)) + 0.5 * len(t) * ca.sum1(rho)
    w = ca.vertcat(a, k, c, d, *x0s, *rhos)
    return w, J


def test_two_manoeuvres_with_their_own_initial_states_equal_a_joint_nlp_written_by_hand():
    first, second = _manoeuvre(1, 0.6, 300), _manoeuvre(2, -0.9, 200, shift=5.0)
    model = oscillator()
    datasets = {name: model.dataset({k: v for k, v in m.items() if k != "x"})
                for name, m in (("m1", first), ("m2", second))}
    est = casest.estimate(model, datasets)
    assert est.success and est.experiments == ("m1", "m2")
    assert est.parameter_names == ("a", "k", "c", "d", "x0@m1", "x0@m2")
    w, J = _hand_written_joint_nlp([first, second])
    solver = ca.nlpsol("joint", "ipopt", {"x": w, "f": J}, {"print_time": False, "ipopt.print_level": 0,
                                                            "ipopt.sb": "yes", "ipopt.tol": 1e-12})
    start = np.concatenate([est.theta * 1.01, np.log(est.R) + 0.1])
    sol = solver(x0=start)
    assert solver.stats()["success"]
    w_hand = np.asarray(sol["x"]).reshape(-1)
    np.testing.assert_allclose(float(sol["f"]), est.cost, rtol=1e-8)
    np.testing.assert_allclose(est.theta, w_hand[:6], rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(est.R, np.exp(w_hand[6:]), rtol=1e-5)
    for name, truth in (("x0@m1", 0.6), ("x0@m2", -0.9)):  # simulated truth, within 3 std
        assert abs(est.values[name] - truth) < 3 * est.stds[name]


def test_manoeuvres_with_initial_states_from_data_restart_at_each_one():
    """Stacked simulation equals each manoeuvre simulated alone (shared R, x(t0) from the data)."""
    s = {n: ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "c", "d")}
    P = casest.Parameter
    model = casest.DynamicModel(
        [P("a", 0.05, 2.0, 0.5), P("k", 0.5, 8.0, 2.0), P("c", -5.0, 5.0, 1.0), P("d", -5.0, 5.0, 0.0)],
        [casest.State("x", "data"), casest.State("v", 0.0)], ["u"],
        {"x": s["v"], "v": -s["k"] * s["x"] - s["a"] * s["v"] + s["u"]},
        {"y1": s["c"] * s["x"] + s["d"], "y2": s["v"]}, name="oscillator", substeps=2, input_hold="cubic")
    records = [model.dataset(_manoeuvre(seed, x0, n)) for seed, x0, n in ((3, 0.4, 120), (4, -0.7, 90), (5, 1.1, 60))]
    problem = casest.Problem(model, records, separate_noise=False)
    theta = problem.vector({k: TRUTH[k] for k in "akcd"})
    stacked = problem.predict(theta)
    alone = np.vstack([model.predict_data(theta, r) for r in records])
    np.testing.assert_allclose(stacked, alone, rtol=1e-12, atol=1e-12)
    est = casest.estimate(problem)
    assert est.success and est.noise_model.startswith("unknown diagonal") and len(est.R) == 2


@pytest.mark.slow
def test_two_stage_function_of_a_dynamic_problem(record):
    """The two-stage Function of a dynamic Problem equals casest.estimate on its data, and its
    derivative with respect to an output sample equals central differences of the Function."""
    from casest.interop import two_stage_function

    model, data = record
    short = model.dataset({n: data.column(n)[:250] for n in ("t", "u", "y1", "y2")})
    problem = casest.Problem(model, short)
    F = two_stage_function(problem, max_starts=2)
    p = problem.data_vector()
    theta, R, cov, success = (np.asarray(v) for v in F(p))
    reference = casest.estimate(problem, max_starts=2)
    np.testing.assert_allclose(theta.reshape(-1), reference.theta, rtol=1e-6, atol=1e-9)
    assert success.item() == 1.0 and np.all(np.isfinite(cov))
    P = ca.MX.sym("p", p.size)
    jacobian = ca.Function("dtheta_dp", [P], [ca.jacobian(F(P)[0], P)])
    k = 250 + 250 + 2 * 40  # the data vector is [t; u; (y1, y2) per sample; ...]: y1 of sample 40
    h = 1e-6
    plus, minus = p.copy(), p.copy()
    plus[k] += h
    minus[k] -= h
    central = (np.asarray(F(plus)[0]) - np.asarray(F(minus)[0])).reshape(-1) / (2 * h)
    exact = np.asarray(jacobian(p))[:, k]
    np.testing.assert_allclose(exact, central, rtol=1e-4, atol=1e-6 * np.abs(exact).max())


@pytest.mark.parametrize("noise", [None, casest.KnownNoise({"y1": 0.05, "y2": 0.02})])
def test_ml_cost_function_of_a_dynamic_problem_equals_the_problem_cost(record, reference, noise):
    """Truth: Problem.cost (paper Eq. 6 from the per-sample sums on the simulated states)."""
    from casest.interop import ml_cost_function

    model, data = record
    problem = casest.Problem(model, data, noise=noise)
    R = reference.R if noise is None else problem.known_R
    J = ml_cost_function(problem)(reference.theta, problem.noise_vector(R), problem.data_vector())
    np.testing.assert_allclose(float(J), problem.cost(reference.theta, R), rtol=1e-10)
