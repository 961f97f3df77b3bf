"""Fisher information, predicted covariance and experiment design.

Expected values: the information J'R^-1J with J from central differences of the model's
predictions; the stage-2 cost Hessian at the truth of noise-free data (where the residual
terms vanish, so it equals the information exactly); the Kiefer-Wolfowitz equivalence
theorem for D-optimal approximate designs under a cost budget.
"""

import subprocess

import casadi as ca
import numpy as np
import pytest

import casest
from casest._casadi.numerics import c_compiler, compiler_available
from casest.design import design_experiment, design_inputs
from casest.design.information import information_function, information_matrix, jacobi_smallest_eigenvalue
from casest.models import OptionError

from conftest import model_file


def central_jacobian(predict, theta, step=1e-6):
    """d vec(predict(theta)) / d theta by central differences, relative steps."""
    cols = []
    for i in range(theta.size):
        h = step * max(1.0, abs(theta[i]))
        e = np.zeros_like(theta)
        e[i] = h
        cols.append((predict(theta + e) - predict(theta - e)).reshape(-1) / (2 * h))
    return np.column_stack(cols)


def test_static_information_equals_finite_difference_jtwj(scalar2):
    model, data = scalar2.model(), scalar2.simulate(1)
    theta, R = model.vector(scalar2.TRUTH), np.array([0.04])
    J = central_jacobian(lambda th: model.predict(th, data.signals), theta)
    expect = J.T @ J / R[0]
    F = np.asarray(information_function(model, data.n_samples)(signals=data.signals.T, theta=theta, R=R)["F"])
    np.testing.assert_allclose(F, expect, rtol=1e-6, atol=1e-8 * np.abs(expect).max())
    np.testing.assert_allclose(information_matrix(model, data, theta, R), F, rtol=1e-12, atol=1e-10)


def test_dynamic_information_equals_finite_difference_jtwj():
    sp = model_file("short_period")
    model, data = sp.model(), sp.simulate(0).subset(slice(0, 400, 4))
    theta = model.vector(sp.TRUTH)
    R = np.array([sp.NOISE_STD[n] ** 2 for n in model.output_names])
    J = central_jacobian(lambda th: model.simulate(th, data)[1], theta)  # sample-major rows
    W = np.tile(1.0 / R, data.n_samples)
    expect = J.T @ (J * W[:, None])
    f = information_function(model, data.n_samples)
    F = np.asarray(f(t=data.signals[:, :1].T, inputs=data.signals[:, 1:].T, theta=theta, R=R)["F"])
    np.testing.assert_allclose(F, expect, rtol=1e-5, atol=1e-7 * np.abs(expect).max())


def test_information_equals_the_stage2_hessian_at_the_optimum_of_noise_free_data():
    # noise-free data: the truth is the optimum and the residual terms of the Hessian vanish,
    # so the cost Hessian's parameter block is exactly the information (known R)
    pitot = model_file("pitot5hole")
    model = pitot.model()
    data = pitot.simulate(0, noise=False, t_end=500.0).subset(slice(0, None, 10))
    theta = model.vector(pitot.TRUTH)
    std = dict(zip(model.output_names, pitot.NAV_NOISE_STD))
    problem = casest.Problem(model, data, noise=casest.KnownNoise(std))
    R = np.array(pitot.NAV_NOISE_STD) ** 2
    with problem.data_argument() as data_arg:
        _, H = problem.cost_hessian()(theta, problem.noise_vector(R), data_arg)
    H = np.asarray(H)[: model.n_parameters, : model.n_parameters]
    out = information_function(model, data.n_samples)(signals=data.signals.T, theta=theta, R=R)
    np.testing.assert_allclose(np.asarray(out["F"]), H, rtol=1e-8, atol=1e-10 * np.abs(H).max())
    np.testing.assert_allclose(np.asarray(out["cov"]), np.linalg.inv(H), rtol=1e-6,
                               atol=1e-9 * np.abs(np.linalg.inv(H)).max())
    assert float(out["D"]) == pytest.approx(np.linalg.slogdet(H)[1], rel=1e-10)


def test_criteria_and_their_signal_derivatives_match_central_differences(scalar2):
    import casadi as ca

    model, data = scalar2.model(), scalar2.simulate(2).subset(slice(0, 30))
    theta, R = model.vector(scalar2.TRUTH), np.array([0.04])
    c = np.array([1.0, -2.0, 0.5, 0.0])
    f = information_function(model, data.n_samples)
    X = ca.MX.sym("X", 1, data.n_samples)
    out = f(signals=X, theta=theta, R=R, c=c)
    crit = ca.vertcat(out["D"], out["A"], out["E"], out["c_var"])
    jac = ca.Function("criteria_jacobian", [X], [ca.jacobian(crit, X)])
    value = ca.Function("value", [X], [crit])
    x0 = data.signals.T.copy()
    analytic = np.asarray(jac(x0))
    # step 1e-4: the eigenvalue (E) is computed to ~eps ||F||, which a smaller step would amplify
    h = 1e-4
    fd = np.zeros_like(analytic)
    for k in range(data.n_samples):
        xp, xm = x0.copy(), x0.copy()
        xp[0, k] += h
        xm[0, k] -= h
        fd[:, k] = (np.asarray(value(xp)) - np.asarray(value(xm))).ravel() / (2 * h)
    scale = np.abs(fd).max(axis=1)
    for row in range(4):  # D, A, E, c_var: each to 1e-6 of its largest derivative
        np.testing.assert_allclose(analytic[row], fd[row], rtol=0, atol=1e-6 * scale[row])
    # the values themselves against NumPy
    F = information_matrix(model, data, theta, R)
    cov = np.linalg.inv(F)
    s = model.scales
    # A: trace of the covariance in units of the scales; E: smallest eigenvalue of the information in them
    expect = [np.linalg.slogdet(F)[1], np.trace(cov / np.outer(s, s)),
              np.linalg.eigvalsh(np.diag(s) @ F @ np.diag(s))[0], c @ cov @ c]
    np.testing.assert_allclose(np.asarray(value(x0)).ravel(), expect, rtol=1e-8)


def test_several_experiments_add_their_information(scalar2):
    model = scalar2.model()
    a, b = scalar2.simulate(3).subset(slice(0, 40)), scalar2.simulate(4).subset(slice(0, 25))
    theta = model.vector(scalar2.TRUTH)
    f = information_function(model, [a.n_samples, b.n_samples])
    F = np.asarray(f(signals_1=a.signals.T, R_1=[0.04], signals_2=b.signals.T, R_2=[0.09], theta=theta)["F"])
    expect = information_matrix(model, a, theta, [0.04]) + information_matrix(model, b, theta, [0.09])
    np.testing.assert_allclose(F, expect, rtol=1e-10)
    np.testing.assert_allclose(information_matrix(model, [a, b], theta, [[0.04], [0.09]]), expect, rtol=1e-12)


def _blocks(scalar2, n_blocks=5, size=20):
    model, data = scalar2.model(), scalar2.simulate(0)
    order = np.argsort(data.signals[:, 0])
    return model, {f"block{k}": data.subset(order[k * size:(k + 1) * size]) for k in range(n_blocks)}


def test_d_optimal_allocation_satisfies_the_equivalence_theorem(scalar2):
    # Kiefer-Wolfowitz with a cost budget: at the D-optimum, trace(F^-1 F_m) / d_m <= n / budget
    # for every candidate, with equality where the design puts weight
    model, cands = _blocks(scalar2)
    durations = {k: 10.0 + 5 * i for i, k in enumerate(cands)}
    budget = 120.0
    design = design_experiment(model, cands, scalar2.TRUTH, [0.04], budget, durations)
    assert design.success
    theta = model.vector(scalar2.TRUTH)
    per = [information_matrix(model, cands[k], theta, [0.04]) for k in cands]
    F = sum(r * Fk for r, Fk in zip(design.repeats, per))
    ratio = np.array([np.trace(np.linalg.solve(F, Fk)) / durations[k] for Fk, k in zip(per, cands)])
    n = model.n_parameters
    assert np.all(ratio <= n / budget * (1 + 1e-5))
    support = design.repeats > 1e-3 * design.repeats.max()
    np.testing.assert_allclose(ratio[support], n / budget, rtol=1e-4)
    assert float(design.repeats @ design.durations) == pytest.approx(budget, rel=1e-6)
    assert design.rounded @ design.durations <= budget


@pytest.mark.parametrize("criterion", ["A", "E", "c"])
def test_other_criteria_beat_the_uniform_design(scalar2, criterion):
    model, cands = _blocks(scalar2)
    theta = model.vector(scalar2.TRUTH)
    c = np.array([0.0, 1.0, 1.0, 0.0])
    design = design_experiment(model, cands, scalar2.TRUTH, [0.04], 100.0, criterion=criterion, c=c)
    assert design.success
    per = [information_matrix(model, cands[k], theta, [0.04]) for k in cands]
    S = np.diag(model.scales)

    def value(lams):
        F = sum(lam * Fk for lam, Fk in zip(lams, per))
        cov = np.linalg.inv(F)
        return {"A": np.trace(np.linalg.inv(S @ F @ S)), "E": -np.linalg.eigvalsh(S @ F @ S)[0], "c": c @ cov @ c}[criterion]

    uniform = np.full(len(cands), 100.0 / (20 * len(cands)))
    assert value(design.repeats) < value(uniform)
    # no better allocation among random ones on the budget
    rng = np.random.default_rng(0)
    for _ in range(200):
        w = rng.dirichlet(np.ones(len(cands))) * 100.0 / 20
        assert value(design.repeats) <= value(w) * (1 + 1e-6)


def test_robust_design_over_guesses_and_clear_errors(scalar2):
    model, cands = _blocks(scalar2)
    far = {k: v * 1.3 for k, v in scalar2.TRUTH.items()}
    worst = design_experiment(model, cands, [scalar2.TRUTH, far], [0.04], 100.0, robust="worst")
    single = design_experiment(model, cands, scalar2.TRUTH, [0.04], 100.0)
    assert worst.success and len(worst.covariance) == 2

    def logdet(design, guess):
        th = model.vector(guess)
        return np.linalg.slogdet(sum(r * information_matrix(model, cands[k], th, [0.04])
                                     for r, k in zip(design.repeats, cands)))[1]

    # the worst-case design is at least as good at its worst guess as the nominal design
    assert min(logdet(worst, g) for g in (scalar2.TRUTH, far)) >= min(logdet(single, g) for g in (scalar2.TRUTH, far)) - 1e-6
    with pytest.raises(OptionError, match="criterion"):
        design_experiment(model, cands, scalar2.TRUTH, [0.04], 100.0, criterion="Z")
    with pytest.raises(OptionError, match="budget"):
        design_experiment(model, cands, scalar2.TRUTH, [0.04], 5.0)
    one = {"block0": cands["block0"].subset(slice(0, 2))}  # 2 samples cannot identify 4 parameters
    with pytest.raises(OptionError, match="unidentified"):
        design_experiment(model, one, scalar2.TRUTH, [0.04], 100.0)


def test_input_design_improves_the_criterion_within_bounds_and_rate_limits():
    sp = model_file("short_period")
    model, data = sp.model(), sp.simulate(0).subset(slice(0, 301, 3))
    R = np.array([sp.NOISE_STD[n] ** 2 for n in model.output_names])
    limit, rate = np.deg2rad(2.0), 1.0
    design = design_inputs(model, data, ["delta_e"], sp.TRUTH, R, {"delta_e": -limit}, {"delta_e": limit},
                           {"delta_e": rate}, max_iter=60)
    u = design.inputs[:, 0]
    assert np.all(np.abs(u) <= limit + 1e-9)
    assert np.all(np.abs(np.diff(u)) <= rate * np.diff(data.signals[:, 0]) + 1e-7)
    assert design.value < design.start_value - 1.0  # ln det F up by more than 1 (std down ~ e^(-1/14) each)
    F = information_matrix(model, design.data, sp.TRUTH, R)
    np.testing.assert_allclose(np.linalg.inv(F), design.covariance[0], rtol=1e-10)
    S = np.diag(model.scales)  # the value is in the parameters' scales: -ln det(S F S)
    assert -np.linalg.slogdet(S @ F @ S)[1] == pytest.approx(design.value, rel=1e-8)


def test_pitot_design_beats_the_papers_schedule_in_predicted_precision():
    # scripts/paper/design_pitot.py's design step: same flight time as the paper's stage-2 schedule,
    # D-optimal over four wind guesses; predicted (Cramer-Rao) at the truth
    import importlib.util
    import os

    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts", "paper", "design_pitot.py")
    spec = importlib.util.spec_from_file_location("design_pitot", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    module = script.load_module()
    model = module.model()
    R = np.array(module.NAV_NOISE_STD) ** 2
    cands = script.candidates(module, 0, noise=False)
    wins = script.candidate_windows()
    durations = {n: wins[n][1] - wins[n][0] + 5.0 for n in cands}
    paper = script.paper_schedule()
    budget = sum(durations[n] * k for n, k in paper.items())
    guesses = [{**{n: 0.0 for n in model.parameter_names}, "W_N": wn, "W_E": we} for wn, we in script.WIND_GUESSES]
    design = design_experiment(model, cands, guesses, R, budget, durations)
    assert design.success
    assert design.rounded @ design.durations <= budget
    truth = model.vector(module.TRUTH)
    logdet = {k: np.linalg.slogdet(script.predicted_cov(model, cands, s, truth, R))[1]
              for k, s in (("paper", paper), ("designed", design.schedule()))}
    assert logdet["designed"] < logdet["paper"] - 1.0  # generalised variance down by more than e


def test_information_function_is_saved_loaded_and_generated(scalar2, tmp_path, monkeypatch):
    """The Function, E included (unrolled Jacobi sweeps), is pure CasADi: saved and loaded it gives
    the same outputs bit for bit, and its generated C compiles and runs to the same outputs; the
    criteria can be chosen (without E the other outputs are the same to the bit)."""
    model, data = scalar2.model(), scalar2.simulate(1)
    theta, R = model.vector(scalar2.TRUTH), np.array([0.04])
    full = information_function(model, data.n_samples)
    pure = information_function(model, data.n_samples, criteria=("D", "A", "c"))
    assert pure.name_out() == ["F", "cov", "D", "A", "c_var"]
    args = dict(signals=data.signals.T, theta=theta, R=R, c=np.ones(model.n_parameters))
    expect, got = full(**args), pure(**args)
    for key in pure.name_out():
        np.testing.assert_array_equal(np.asarray(got[key]), np.asarray(expect[key]))
    path = str(tmp_path / "information.casadi")
    full.save(path)
    loaded = ca.Function.load(path)
    for key, value in loaded(**args).items():
        np.testing.assert_array_equal(np.asarray(value), np.asarray(expect[key]))
    if not compiler_available():
        pytest.skip("no C compiler for the generated code")
    monkeypatch.chdir(tmp_path)  # the C file is written in the working folder
    source = full.generate("information_c", {"with_header": False})
    subprocess.run([c_compiler(), "-O1", "-shared", "-fPIC", source, "-o", "information_c.so"], check=True)
    external = ca.external(full.name(), str(tmp_path / "information_c.so"))
    for key, value in external(**args).items():
        np.testing.assert_allclose(np.asarray(value), np.asarray(expect[key]), rtol=1e-12, atol=0)
    with pytest.raises(casest.models.OptionError, match="unknown design criteria"):
        information_function(model, data.n_samples, criteria=("G",))


@pytest.mark.parametrize("n", [2, 3, 6, 10])
def test_jacobi_smallest_eigenvalue_equals_lapack_with_its_derivatives(n):
    """E by unrolled Jacobi sweeps against LAPACK (numpy.linalg.eigh) on random symmetric positive
    definite matrices, graded ones among them (eigenvalues over 1e0..1e12, rows scaled by up to 1e4,
    a nearly double smallest eigenvalue): the value to 20 eps times the largest eigenvalue; the
    gradient equals v v' (v: LAPACK's unit eigenvector) to 1e-8 relative to the gap's share; the
    Hessian equals central differences of the gradient to 1e-6."""
    F = ca.SX.sym("F", n, n)
    E = jacobi_smallest_eigenvalue(0.5 * (F + F.T))
    value = ca.Function("E", [F], [E])
    gradient = ca.Function("dE", [F], [ca.gradient(E, F)])
    hessian = ca.Function("d2E", [F], [ca.hessian(E, F)[0]])
    rng = np.random.default_rng(n)
    for trial in range(20):
        Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
        lam = np.logspace(0, rng.uniform(0, 12), n)
        if trial % 4 == 1:
            lam[1] = lam[0] * (1 + 1e-3)
        A = Q @ np.diag(lam) @ Q.T
        if trial % 3 == 0:
            A = A * np.outer(np.logspace(0, 4, n), np.logspace(0, 4, n))
        A = 0.5 * (A + A.T)
        w, V = np.linalg.eigh(A)
        assert abs(float(value(A)) - w[0]) <= 20 * np.finfo(float).eps * w[-1]
        gap = (w[1] - w[0]) / w[-1]
        g = 0.5 * (np.asarray(gradient(A)) + np.asarray(gradient(A)).T)  # d/dF of E(sym F)
        assert np.abs(g - np.outer(V[:, 0], V[:, 0])).max() * gap <= 1e-8
    A = np.diag(np.arange(1.0, n + 1)) + 0.1 * np.ones((n, n))  # well separated: second derivatives
    H = np.asarray(hessian(A))
    step = 1e-6
    for k in range(n * n):
        dA = np.zeros(n * n)
        dA[k] = step
        dA = dA.reshape(n, n, order="F")
        fd = (np.asarray(gradient(A + dA)) - np.asarray(gradient(A - dA))).reshape(-1, order="F") / (2 * step)
        np.testing.assert_allclose(H[:, k], fd, atol=1e-6 * max(np.abs(H).max(), 1.0))
