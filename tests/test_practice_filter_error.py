"""Filter error's practice (innovation) formulation on a turbulent nonlinear record, and its failure paths.

Truths: the record of ``models/turbulent_longitudinal.py`` (simulated with a finer RK4 than the
model's, white turbulence on every state rate; the truth is ``TRUTH``); the hand-written NumPy
implementation of the textbook's algorithm with a diagonal innovation covariance
(``tests/practice_numpy.py``, complex-step sensitivities, started from the truth); the exact
minimiser of a small quadratic programme by enumerating its active sets.
"""

import itertools
import json

import numpy as np
import pytest

import casest
from casest.filter_error import relaxation
from casest.filter_error.innovation import InnovationProblem
from casest.filter_error.practice_steps import StepOutcome, least_distance_step, practice_step
from casest.status import NoteCode

TURBULENT = casest.load_model_file("turbulent_longitudinal")
#: the seed whose record has diag(K C) <= 1 active at the optimum (alpha's entry 1)
ACTIVE_SEED = 1
CONSTANTS = {n: getattr(TURBULENT, n) for n in ("G", "RHO", "S_REF", "CBAR", "MASS", "IY", "SIGMA_T", "V0")}


def _by_enumeration(M, g, A, b):
    """The QP's minimiser: every active set's KKT point, the feasible one with non-negative multipliers."""
    n, m = g.size, b.size
    for size in range(m + 1):
        for active in itertools.combinations(range(m), size):
            Aa = A[list(active)]
            K = np.block([[M, Aa.T], [Aa, np.zeros((size, size))]])
            try:
                sol = np.linalg.solve(K, np.concatenate([-g, b[list(active)]]))
            except np.linalg.LinAlgError:
                continue
            d, lam = sol[:n], sol[n:]
            if np.all(A @ d <= b + 1e-10) and np.all(lam >= -1e-10):
                return d
    raise AssertionError("no KKT point")


def test_the_least_distance_step_is_the_qps_minimiser():
    rng = np.random.default_rng(5)
    for _ in range(20):
        L = rng.standard_normal((4, 4))
        M, g = L @ L.T + 0.1 * np.eye(4), rng.standard_normal(4)
        A, b = rng.standard_normal((5, 4)), rng.uniform(0.0, 0.5, 5)  # d = 0 feasible
        d, lam = least_distance_step(M, g, A, b)
        np.testing.assert_allclose(d, _by_enumeration(M, g, A, b), atol=1e-9)
        assert np.all(lam >= 0) and np.all(A @ d <= b + 1e-9)


def test_a_step_whose_trials_are_all_nan_is_rejected():
    w = np.array([1.0, 2.0])
    step = practice_step(w, 1.0, np.array([1.0, 1.0]), np.eye(2), np.array([0.5]), np.zeros((1, 2)),
                         (np.full(2, -10.0), np.full(2, 10.0)), lambda trial: (np.nan, np.array([0.5])))
    assert step.outcome is StepOutcome.NOT_FINITE and step.halvings == 10
    np.testing.assert_array_equal(step.w, w)  # nothing accepted


def test_an_estimate_whose_filter_turns_nan_fails_with_a_coded_note(monkeypatch):
    """Every trial point's cost NaN (a filter that diverges there): the relaxation stops at the
    start, success False, status Not_Finite, a NOT_FINITE note; never a NaN iterated on."""
    from casest.filter_error.scoring import InnovationDerivatives

    model, data = TURBULENT.model(), TURBULENT.simulate(0, n_samples=200)
    monkeypatch.setattr(InnovationDerivatives, "value", lambda self, w, p: np.nan)
    fe = casest.filter_error_estimate(model, data, TURBULENT.TURBULENCE_START, start=TURBULENT.START,
                                      formulation="innovation")
    assert not fe.success and fe.status == "Not_Finite"
    assert any(n.code is NoteCode.NOT_FINITE and "NaN or infinite" in str(n) for n in fe.notes)
    assert np.all(np.isfinite(fe.theta)) and fe.n_rounds == 1 and fe.n_iterations == 0


def test_the_relaxation_rounds_are_settable_and_counted_apart():
    model, data = TURBULENT.model(), TURBULENT.simulate(0, n_samples=200)
    fe = casest.filter_error_estimate(model, data, TURBULENT.TURBULENCE_START, start=TURBULENT.START,
                                      formulation="innovation", max_rounds=2)
    assert not fe.success and fe.status == "Maximum_Rounds_Exceeded" and fe.n_rounds == 2
    assert any(n.code is NoteCode.NOT_VERIFIED and "max_rounds" in str(n) for n in fe.notes)
    assert "Gauss-Newton steps in 2 relaxation rounds" in fe.report()
    with pytest.raises(casest.OptionError, match="max_rounds"):
        casest.filter_error_estimate(model, data, TURBULENT.TURBULENCE_START, formulation="innovation", max_rounds=0)
    with pytest.raises(casest.OptionError, match="innovation_covariance"):
        casest.filter_error_estimate(model, data, TURBULENT.TURBULENCE_START, formulation="innovation",
                                     innovation_covariance="diag")


@pytest.fixture(scope="module")
def as_a_user_calls_it():
    """The call of the practice case: four noisy states, the textbook-like start, Fisher std."""
    model, data = TURBULENT.model(), TURBULENT.simulate(ACTIVE_SEED)
    fe = casest.filter_error_estimate(model, data, TURBULENT.TURBULENCE_START, start=TURBULENT.START,
                                      formulation="innovation", covariance="fisher")
    return model, data, fe


def test_the_practice_case_converges_with_what_the_result_holds(as_a_user_calls_it, tmp_path):
    model, data, fe = as_a_user_calls_it
    assert fe.success and fe.status == "Solve_Succeeded", fe.notes
    truth = model.vector(TURBULENT.TRUTH)
    assert np.all(np.abs(fe.theta - truth) < 3 * fe.std), (fe.theta - truth) / fe.std
    # theta's process noise (truth 1e-7) sits on its bound 0 with a coded note, not dropped and not NaN
    assert fe.process_noise["theta"] == 0.0 and set(fe.process_noise) == set(TURBULENT.STATES)
    assert any(n.code is NoteCode.BOUNDS and "theta" in str(n) for n in fe.notes)
    # the Cramer-Rao std of the diagonal form with correlated innovations: said, with the remedy
    assert any(n.code is NoteCode.NOISE_MODEL and "covariance='sandwich'" in str(n) for n in fe.notes)
    # the innovation covariance under its own name, diagonal, with its large-sample std
    Ri = fe.innovation_covariance
    assert Ri.shape == (7, 7) and np.count_nonzero(Ri - np.diag(np.diag(Ri))) == 0
    np.testing.assert_allclose(np.diag(fe.innovation_covariance_std), np.diag(Ri) * np.sqrt(2 / data.n_samples))
    assert np.all(np.isnan(fe.R_std)) and not fe.R_estimated and np.all(fe.R[np.isfinite(fe.R)] >= 0)
    report = fe.report()
    assert "[[Innovation covariance]]" in report and "not estimated: no std" in report and "+/- 0\n" not in report
    back = casest.FilterErrorEstimate.from_json(fe.to_json(str(tmp_path / "fe.json")))
    np.testing.assert_array_equal(back.innovation_covariance, Ri)
    assert back.n_rounds == fe.n_rounds and json.loads(fe.to_json())["n_rounds"] == fe.n_rounds


def test_the_practice_case_holds_its_filter_and_f_with_its_std(as_a_user_calls_it):
    """The innovations the estimate holds are those whose closed-form covariance it reports (their
    mean square equals its diagonal to 1e-6 relative: the relaxation ends on R's fixed point), the
    gain respects diag(K C) <= 1, and F's std are the covariance's own rows (F is the decision
    variable here)."""
    model, data, fe = as_a_user_calls_it
    E = fe.innovations
    np.testing.assert_allclose(np.mean(E**2, axis=0), np.diag(fe.innovation_covariance), rtol=1e-6)
    assert all(v <= 1.0 + 1e-9 for v in fe.kc_diagonal.values()) and fe.gain.shape == (4, 7)
    npar = model.n_parameters
    assert fe.decision_names[npar:] == ("F[V]", "F[alpha]", "F[theta]", "F[q]")
    rows = np.sqrt(np.diag(fe.covariance))[npar:]
    np.testing.assert_allclose([fe.process_noise_distribution_std[n] for n in ("V", "alpha", "q")], rows[[0, 1, 3]],
                               rtol=1e-10)
    assert np.isnan(fe.process_noise_distribution_std["theta"])  # on its bound 0: no std


def test_the_practice_case_has_what_a_real_turbulent_record_has(as_a_user_calls_it):
    """Correlated innovations (a_x with a_z), diag(K C) <= 1 active at the optimum (alpha's entry),
    and a first R (the output-error residuals at the start) 10-100 times and more off."""
    model, data, fe = as_a_user_calls_it
    noisy = tuple(range(4))
    problem = InnovationProblem.of(model, data.n_samples, noisy)
    record = problem.record_part(data)
    f = np.sqrt([fe.process_noise[s] for s in TURBULENT.STATES])
    x0 = data.outputs[0, :4]
    p = problem.parameters(record, fe.innovation_covariance, x0, data.signals[0, 1:], f)
    E, kc, *_ = (np.asarray(v) for v in problem.values(np.concatenate([fe.theta / model.scales, f]), p))
    assert abs(np.corrcoef(E)[5, 6]) > 0.5
    assert kc.reshape(-1)[1] == pytest.approx(1.0, abs=1e-8)
    f0 = np.sqrt([TURBULENT.TURBULENCE_START[s] for s in TURBULENT.STATES])
    w0 = np.concatenate([model.vector(TURBULENT.START) / model.scales, f0])
    quiet = w0.copy()
    quiet[model.n_parameters:] = 0.0
    spread = np.cov(data.outputs.T, bias=True)
    residuals = np.asarray(problem.values(quiet, problem.parameters(record, spread, x0, data.signals[0, 1:],
                                                                     np.zeros(4)))[0])
    ratio = np.diag(relaxation.closed_form_covariance(residuals, True)) / np.diag(fe.innovation_covariance)
    assert np.all(ratio > 5) and np.median(ratio) > 10, ratio


@pytest.mark.slow
def test_the_practice_case_equals_the_numpy_textbook_algorithm():
    """casest from the textbook-like start against the NumPy algorithm from the truth, the three
    noisy states whose F is not at a bound: theta, F and R equal to 1e-8 (relative, or 1e-8 std
    where a value is smaller than its std)."""
    from practice_numpy import practice_algorithm

    model, data = TURBULENT.model(), TURBULENT.simulate(ACTIVE_SEED)
    noisy = ["V", "alpha", "q"]
    theta, f, R = practice_algorithm(data, CONSTANTS, model.vector(TURBULENT.TRUTH),
                                     np.sqrt([TURBULENT.TURBULENCE[s] for s in noisy]),
                                     [TURBULENT.STATES.index(s) for s in noisy])
    fe = casest.filter_error_estimate(model, data, {s: TURBULENT.TURBULENCE_START[s] for s in noisy},
                                      start=TURBULENT.START, formulation="innovation", settle_std=0)
    assert fe.success and "was active" in fe.notes[0], fe.notes
    assert np.all(np.abs(fe.theta - theta) <= 1e-8 * np.maximum(np.abs(theta), fe.std))
    np.testing.assert_allclose(np.sqrt([fe.process_noise[s] for s in noisy]), f, rtol=1e-8)
    np.testing.assert_allclose(np.diag(fe.innovation_covariance), R, rtol=1e-8)


def _sandwich_std(model, data, fe):
    """The coefficients' std of ``covariance="sandwich"`` at an estimate, without estimating again
    (the F at their bound held, as the estimator holds them)."""
    f = np.sqrt([fe.process_noise[s] for s in TURBULENT.STATES])
    problem = InnovationProblem.of(model, data.n_samples, tuple(range(4)))
    p = problem.parameters(problem.record_part(data), fe.innovation_covariance, data.outputs[0, :4],
                           data.signals[0, 1:], f)
    E, _, dE, _ = problem.derivatives(np.concatenate([fe.theta / model.scales, f]), p)
    M, B = relaxation.sandwich_middle(E, dE, fe.innovation_covariance)
    free = np.r_[np.ones(model.n_parameters, dtype=bool), f > 0]
    Mi = np.linalg.inv(M[np.ix_(free, free)])
    return np.sqrt(np.diag(Mi @ B[np.ix_(free, free)] @ Mi))[:model.n_parameters] * model.scales


@pytest.mark.slow
def test_eight_turbulent_records_recover_the_truth_within_three_std():
    """Seeds 0-7 as a user calls it: every coefficient within 3 Cramer-Rao std of the truth and the
    mean z within 3 / sqrt(8) of 0; the sandwich std (the estimator's own covariance) within a
    factor 2.5 of the eight estimates' spread for every coefficient, where the Cramer-Rao std
    overstate it (the larger Monte-Carlo set: scripts/campaigns/practice_filter_error.py)."""
    model = TURBULENT.model()
    truth = model.vector(TURBULENT.TRUTH)
    z, thetas, sandwich = [], [], []
    for seed in range(8):
        data = TURBULENT.simulate(seed)
        fe = casest.filter_error_estimate(model, data, TURBULENT.TURBULENCE_START, start=TURBULENT.START,
                                          formulation="innovation", covariance="fisher")
        assert fe.success, (seed, fe.notes)
        z.append((fe.theta - truth) / fe.std)
        thetas.append(fe.theta)
        sandwich.append(_sandwich_std(model, data, fe))
    z = np.array(z)
    assert np.all(np.abs(z) < 3), z
    assert np.all(np.abs(z.mean(axis=0)) < 3 / np.sqrt(8)), z.mean(axis=0)
    ratio = np.std(thetas, axis=0, ddof=1) / np.mean(sandwich, axis=0)
    assert np.all((ratio > 0.4) & (ratio < 2.5)), ratio


def test_the_sandwich_is_the_innovation_forms_own(as_a_user_calls_it):
    """covariance="sandwich" reports M^-1 B M^-1 (the helper above computes it from the estimate);
    the other forms refuse it."""
    model, data, fe = as_a_user_calls_it
    sandwich = casest.filter_error_estimate(model, data, TURBULENT.TURBULENCE_START, start=TURBULENT.START,
                                            formulation="innovation", covariance="sandwich")
    np.testing.assert_allclose(sandwich.theta, fe.theta, rtol=1e-12)
    np.testing.assert_allclose(sandwich.std, _sandwich_std(model, data, fe), rtol=1e-6)
    assert not any("covariance='sandwich' gives" in str(n) for n in sandwich.notes)
    with pytest.raises(casest.OptionError, match="sandwich"):
        casest.filter_error_estimate(model, TURBULENT.simulate(0, n_samples=100), TURBULENT.TURBULENCE_START,
                                     formulation="steady-state", covariance="sandwich")


def test_a_process_noise_that_is_not_finite_is_reported_as_nan_with_a_note():
    """An F that turned NaN is kept (as NaN) and named in a NOT_FINITE note, never dropped."""
    from casest.filter_error.uncertainty import HeldCovariance
    from casest.filter_error.innovation_result import _noise_notes

    model = TURBULENT.model()
    f = np.array([0.1, np.nan, 0.0, 0.005])
    uncertainty = HeldCovariance(np.eye(15), np.ones(15), [None] * 15, np.zeros(15, dtype=bool), False)
    notes = _noise_notes(model, f, np.full(7, 1e-4), uncertainty, [0, 1, 2, 3])
    assert any(n.code is NoteCode.NOT_FINITE and "['alpha']" in str(n) for n in notes)


def test_the_std_stopping_rule_ends_within_a_hundredth_of_a_std_of_the_fixed_point():
    """The default relaxation (settle_std=0.01) against settle_std=0 (the fixed point to rounding)
    on the practice case (seed 1) and on seeds 2 and 5 (not used to choose the rule's details):
    every coefficient and every process-noise F within 0.05 std of the fixed point (the issue's
    target; measured about 1e-4), the same F on the bound 0, fewer Gauss-Newton iterations, and
    the rule stated in the formulation's note."""
    model = TURBULENT.model()
    for seed in (ACTIVE_SEED, 2, 5):
        data = TURBULENT.simulate(seed)
        fast, full = (casest.filter_error_estimate(model, data, TURBULENT.TURBULENCE_START, start=TURBULENT.START,
                                                   formulation="innovation", covariance="fisher", settle_std=s)
                      for s in (0.01, 0.0))
        assert fast.success and full.success, (seed, fast.notes, full.notes)
        assert np.all(np.abs(fast.theta - full.theta) <= 0.05 * full.std), seed
        for state, q in full.process_noise.items():
            assert (q == 0.0) == (fast.process_noise[state] == 0.0), (seed, state)
            if q > 0.0:  # F = sqrt(q), its std by the delta method
                f_std = full.process_noise_std[state] / (2.0 * np.sqrt(q))
                assert abs(np.sqrt(fast.process_noise[state]) - np.sqrt(q)) <= 0.05 * f_std, (seed, state)
        assert fast.n_iterations < full.n_iterations, seed
        assert "settle_std=0.01" in fast.notes[0] and "fixed point's rounding" in full.notes[0]


def test_settle_std_must_be_a_fraction():
    model, data = TURBULENT.model(), TURBULENT.simulate(ACTIVE_SEED)
    for bad in (-0.1, 1.0, float("nan"), "0.01"):
        with pytest.raises(casest.OptionError, match="settle_std must be a fraction"):
            casest.filter_error_estimate(model, data, TURBULENT.TURBULENCE_START, formulation="innovation",
                                         settle_std=bad)
