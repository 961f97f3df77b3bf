"""The problem layer (casest.Problem) and the stages that consume it.

Truths: (1) Problem.cost equals paper Eq. 6 written out in NumPy in this file (per-channel
counts N_j with missing outputs, a full R by its Cholesky factor, a known R, a Gaussian prior
penalty) to 1e-12 relative; (2) casest.estimate(Problem(...)) is the same computation as
casest.estimate(model, data, options) (equal to 1e-12); (3) the embedding API built from a
Problem (missing outputs, several experiments, known R, full R, MAP) solved by IPOPT reaches
the estimate of casest.estimate (theta to 1e-6 relative, the same cost to 1e-9) and its
standard deviations equal the estimate's (1e-6).
"""

import os

import casadi as ca
import numpy as np
import pytest

import casest
from casest.apps.baselines import multistart
from casest.interop import add_to_opti, ml_problem

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
hard = casest.load_model_file(os.path.join(REPO, "models", "robustness.py"))
scalar1 = casest.load_model_file("scalar1")


def _gapped_triad(seed=1, fraction=0.3):
    model, data = hard.triad(seed)
    outputs = data.outputs.copy()
    outputs[np.random.default_rng(seed).random(data.n_samples) < fraction, 1] = np.nan
    return model, casest.Dataset.from_arrays(model, data.signals, outputs, missing="allow")


def test_cost_equals_eq6_written_out():
    model, data = _gapped_triad()
    problem = casest.Problem(model, data)
    theta = model.nominal * 1.1 + 0.01
    resid = data.outputs - model.predict(theta, data.signals)
    R = np.array([0.3, 1.2, 2.5])
    counts = np.sum(np.isfinite(resid), axis=0)
    expected = 0.5 * np.nansum(resid**2 / R) + 0.5 * np.sum(counts * np.log(R))
    assert problem.cost(theta, R) == pytest.approx(expected, rel=1e-12)
    # the profile cost: R at the per-channel mean square of the measured residuals
    ms = np.nansum(resid**2, axis=0) / counts
    assert problem.profile_cost(theta) == pytest.approx(0.5 * np.sum(counts * (np.log(ms) + 1)), rel=1e-12)
    np.testing.assert_allclose(problem.residual_mean_square(theta), ms, rtol=1e-12)


def test_full_known_and_penalised_costs_equal_eq6_written_out():
    model, data = hard.triad(2)
    theta = model.nominal * 0.9
    resid = data.outputs - model.predict(theta, data.signals)
    A = np.array([[1.0, 0.2, 0.1], [0.2, 2.0, -0.3], [0.1, -0.3, 3.0]])
    expected = 0.5 * np.einsum("ki,ij,kj->", resid, np.linalg.inv(A), resid) + 0.5 * data.n_samples * np.log(
        np.linalg.det(A))
    full = casest.Problem(model, data, noise=casest.CorrelatedNoise())
    assert full.cost(theta, A) == pytest.approx(expected, rel=1e-12)
    np.testing.assert_allclose(full.noise_of(full.noise_vector(A)), A, rtol=1e-12)
    std = {"mx": 0.5, "my": 1.0, "mz": 2.0}
    known = casest.Problem(model, data, noise=casest.KnownNoise(std))
    R = np.array([0.25, 1.0, 4.0])
    assert known.cost(theta) == pytest.approx(0.5 * np.sum(resid**2 / R) + 0.5 * data.n_samples * np.sum(np.log(R)),
                                              rel=1e-12)

    # scalar example 1 declares a ~ N(0, 1), c ~ N(0, 1): MAP adds (a^2 + c^2) / 2
    model, data = scalar1.model(), scalar1.simulate(0)
    theta = np.array([0.7, 0.4, -1.3])
    plain, penalised = casest.Problem(model, data), casest.Problem(model, data, prior_penalty=True)
    assert penalised.cost(theta, [0.2]) == pytest.approx(plain.cost(theta, [0.2]) + 0.5 * (0.7**2 + 1.3**2), rel=1e-12)


def test_vector_accepts_all_or_free_parameters():
    model, data = scalar1.model(), scalar1.simulate(0)
    problem = casest.Problem(model, data, fixed={"b": 0.1})
    full = model.nominal.copy()
    free = problem.vector(full)
    assert problem.model.n_parameters == model.n_parameters - 1 and free.size == problem.model.n_parameters
    np.testing.assert_array_equal(problem.vector(free), free)
    np.testing.assert_array_equal(problem.vector(dict(zip(model.parameter_names, full))), free)
    with pytest.raises(casest.ModelError):
        problem.vector(full[:1])


def test_estimate_of_a_problem_is_the_estimate_with_options():
    model = scalar1.model()
    experiments = [scalar1.simulate(0), scalar1.simulate(1).subset(np.arange(60))]
    options = {"noise": casest.KnownNoise({"z": 0.3}), "fixed": {"b": 0.1}}
    direct = casest.estimate(model, experiments, **options)
    via = casest.estimate(casest.Problem(model, experiments, **options))
    assert direct.success and via.success
    np.testing.assert_allclose(via.theta, direct.theta, rtol=1e-12)
    np.testing.assert_allclose(via.std, direct.std, rtol=1e-12, equal_nan=True)
    assert via.experiments == direct.experiments and via.fixed_parameters == ("b",)
    with pytest.raises(casest.OptionError, match="from the Problem"):
        casest.estimate(casest.Problem(model, experiments), noise=casest.KnownNoise({"z": 0.3}))


def _solve_ml(ml: "casest.interop.embed.MLProblem", x0) -> np.ndarray:
    lbx, ubx = ml.bounds()
    solver = ml.solver(casest.SolverSettings(tol=1e-12))
    sol = solver(x0=x0, p=ml.data_vector(), lbx=lbx, ubx=ubx)
    assert solver.stats()["success"]
    return np.asarray(sol["x"]).ravel()


@pytest.mark.parametrize("case", ["missing", "experiments", "known", "full", "map"])
def test_embedded_problem_reaches_the_estimate(case):
    model, data = hard.triad(3)
    if case == "missing":
        problem = casest.Problem(*_gapped_triad(3))
    elif case == "experiments":
        problem = casest.Problem(model, [data.subset(np.arange(0, 150)), data.subset(np.arange(150, data.n_samples))])
    elif case == "known":
        problem = casest.Problem(model, data, noise=casest.KnownNoise({"mx": 0.4, "my": 0.9, "mz": 1.5}))
    elif case == "full":
        problem = casest.Problem(model, data, noise=casest.CorrelatedNoise())
    else:  # scalar example 1 has Gaussian priors on a and c
        problem = casest.Problem(scalar1.model(), scalar1.simulate(3), prior_penalty=True)
    est = casest.estimate(problem)
    assert est.success
    ml = ml_problem(problem)
    R = est.R_full if case == "full" else est.R
    # start away from the optimum: the ML solve has to find it
    x = _solve_ml(ml, ml.x0(est.theta + 0.02 * problem.model.scales, R))
    theta, R_hat = ml.unpack(x)
    np.testing.assert_allclose(theta, est.theta, rtol=1e-6, atol=1e-8 * np.max(np.abs(est.theta)))
    assert problem.cost(theta, R_hat) == pytest.approx(est.cost, rel=1e-9, abs=1e-9)


def test_add_to_opti_with_experiments_and_missing_outputs_gives_the_estimate_and_its_std():
    model, gapped = _gapped_triad(4)
    model_b, other = hard.triad(5)
    problem = casest.Problem(model, {"first": gapped, "second": other})
    est = casest.estimate(problem)
    assert est.success
    opti = ca.Opti()
    emb = add_to_opti(opti, problem)
    emb.minimize()
    emb.set_initial(est.theta * 1.01, est.R)
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes", "tol": 1e-12})
    sol = opti.solve()
    theta, R = emb.values(sol)
    np.testing.assert_allclose(theta, est.theta, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(R, est.R, rtol=1e-5)
    unc = emb.standard_deviations(sol)
    np.testing.assert_allclose(unc.std, est.std, rtol=1e-5)


def test_multistart_reference_on_a_problem_with_experiments():
    model = scalar1.model()
    problem = casest.Problem(model, [scalar1.simulate(2), scalar1.simulate(3)])
    best, costs = multistart(problem, n_starts=8)
    est = casest.estimate(problem)
    assert best.success and np.isfinite(costs).any()
    assert problem.profile_cost(best.theta) == pytest.approx(est.cost, rel=1e-8)


def test_the_noise_model_is_the_problems_alone(scalar2):
    """The pre-release noise keywords of solve_stage2 and parameter_uncertainty are gone: the
    Problem declares the noise model (a Python TypeError names a keyword given anyway)."""
    model, data = scalar2.model(), scalar2.simulate(0)
    with pytest.raises(TypeError, match="known_R"):
        casest.solve_stage2(model, data, model.nominal, known_R=np.full(model.n_outputs, 0.09))
    with pytest.raises(TypeError, match="r_known"):
        casest.parameter_uncertainty(model, data, model.nominal, np.full(model.n_outputs, 0.09), r_known=True)
