"""Several experiments sharing the parameters.

Truths: (1) two experiments of scalar example 2 (seeds 0 and 1, the second with noise std
0.6) with separate R equal one joint NLP written by hand in CasADi (IPOPT, exact Hessian),
J = sum_e [1/2 sum_k (z_ek - h_ek)^2 / R_e + N_e/2 ln R_e], to 1e-8; (2) four experiments of
the same noise shrink the std by about sqrt(4) = 2 against one (statistical: ratio in
[0.4, 0.6]); (3) shared R equals the stacked samples.
"""

import casadi as ca
import numpy as np
import pytest

import casest

scalar2 = casest.load_model_file("scalar2")


def _experiment(seed, std=0.3):
    model = scalar2.model()
    data = scalar2.simulate(seed)
    truth = model.predict(model.vector(scalar2.TRUTH), data.signals)[:, 0]
    noise = np.random.default_rng(100 + seed).standard_normal(data.n_samples) * std
    return casest.Dataset(model, {"eta": data.column("eta"), "z": truth + noise})


def test_two_experiments_equal_a_hand_written_joint_nlp():
    model = scalar2.model()
    e1, e2 = _experiment(0), _experiment(1, std=0.6)
    est = casest.estimate(model, {"first": e1, "second": e2})
    assert est.success and est.experiments == ("first", "second")
    assert est.output_names == ("z@first", "z@second")
    theta = ca.SX.sym("theta", 4)
    rho = ca.SX.sym("rho", 2)
    J = 0
    for k, d in enumerate((e1, e2)):
        h = model.function.map(d.n_samples)(d.signals.T, theta)
        J += 0.5 * ca.sumsqr(d.outputs[:, 0] - h.T) * ca.exp(-rho[k]) + 0.5 * d.n_samples * rho[k]
    solver = ca.nlpsol("joint", "ipopt", {"x": ca.vertcat(theta, rho), "f": J},
                       {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-12})
    x0 = np.concatenate([est.theta * 1.01, np.log(est.R) + 0.1])
    lb = np.concatenate([model.lower_bounds, [-50, -50]])
    ub = np.concatenate([model.upper_bounds, [50, 50]])
    sol = np.asarray(solver(x0=x0, lbx=lb, ubx=ub)["x"]).ravel()
    np.testing.assert_allclose(est.theta, sol[:4], rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(est.R, np.exp(sol[4:]), rtol=1e-8)


def test_four_experiments_shrink_the_std():
    model = scalar2.model()
    one = casest.estimate(model, _experiment(10))
    four = casest.estimate(model, [_experiment(s) for s in (10, 11, 12, 13)])
    ratio = four.std / one.std
    assert np.all((ratio > 0.4) & (ratio < 0.6)), ratio


def test_shared_noise_equals_stacked_samples():
    model = scalar2.model()
    e1, e2 = _experiment(3), _experiment(4)
    est = casest.estimate(model, [e1, e2], separate_noise=False)
    stacked = casest.Dataset.from_arrays(model, np.vstack([e1.signals, e2.signals]), np.vstack([e1.outputs, e2.outputs]))
    ref = casest.estimate(model, stacked)
    np.testing.assert_allclose(est.theta, ref.theta, rtol=1e-9)
    np.testing.assert_allclose(est.std, ref.std, rtol=1e-9)
    with pytest.raises(casest.DataError, match="not a casest.Dataset"):
        casest.estimate(model, [e1, "e2.csv"])


def test_experiments_with_the_other_options():
    """Fixed parameters and known noise carry over to every experiment; a full R per experiment is refused."""
    model = scalar2.model()
    e1, e2 = _experiment(5), _experiment(6)
    est = casest.estimate(model, [e1, e2], fixed={"a": 1.0})
    assert est.success and est.values["a"] == 1.0 and est.output_names == ("z@e1", "z@e2")
    known = casest.estimate(model, [e1, e2], noise=casest.KnownNoise({"z": 0.3}))
    np.testing.assert_array_equal(known.R, [0.09, 0.09])
    with pytest.raises(ValueError, match="separate_noise=False"):
        casest.estimate(model, [e1, e2], noise=casest.CorrelatedNoise())

