"""Filter-error ML with the steady-state Kalman gain (flight-test practice).

Truths: a hand-written NumPy Riccati solution (scipy.linalg.solve_discrete_are) and
innovation recursion for the linear closed-loop oscillator of test_filters (its RK4 step
with two substeps written out as matrices), to 1e-10; the simulated truth of that record
(process noise on the rate), estimates within 3 std.
"""

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

import casest
from casest.errors import DataError, OptionError
from casest.status import StdReason
from casest.filter_error.steady import steady_filter_error_cost
from test_filters import LOOP_DT, LOOP_NOISE, LOOP_Q, LOOP_TRUTH, loop_model, loop_record


def numpy_steady_cost(data, a, k, b, q, R):
    """V = 1/2 sum e' S^-1 e + N/2 ln det S with the DARE's gain, for x'' = -k x - a x' + b u (zoh, RK4 x 2)."""
    return numpy_steady_filter(data, a, k, b, q, R)[0]


def numpy_steady_filter(data, a, k, b, q, R):
    """The DARE's steady filter of the oscillator written out in NumPy: V, K, S and the innovations (N, 2)."""
    A, B = np.array([[0.0, 1.0], [-k, -a]]), np.array([0.0, b])
    h = LOOP_DT / 2
    hA = h * A
    M = np.eye(2) + hA + hA @ hA / 2 + hA @ hA @ hA / 6 + hA @ hA @ hA @ hA / 24
    G = h * (np.eye(2) + hA / 2 + hA @ hA / 6 + hA @ hA @ hA / 24) @ B
    Phi, Gamma = M @ M, M @ G + G
    Qc = np.diag([0.0, q])
    Qd = 0.5 * LOOP_DT * (Phi @ Qc @ Phi.T + Qc)
    C = np.eye(2)
    P = solve_discrete_are(Phi.T, C.T, Qd, np.diag(R))
    S = C @ P @ C.T + np.diag(R)
    K = P @ C.T @ np.linalg.inv(S)
    Si = np.linalg.inv(S)
    x, V, E = np.zeros(2), 0.0, []
    for y, u in zip(data.outputs, data.signals[:, 1]):
        e = y - C @ x
        V += 0.5 * e @ Si @ e
        E.append(e)
        x = Phi @ (x + K @ e) + Gamma * u
    return V + 0.5 * len(data.outputs) * np.log(np.linalg.det(S)), K, S, np.array(E)


def test_steady_cost_equals_numpy_riccati_and_innovations():
    model = loop_model()
    data = loop_record(model, 3, N=300)
    theta, q, R = np.array([0.8, 3.5, 1.2]), 0.07, np.array([0.002, 0.004])
    V = steady_filter_error_cost(model, data, theta, [0.0, q], R)
    np.testing.assert_allclose(V, numpy_steady_cost(data, *theta, q, R), rtol=1e-10)


@pytest.fixture(scope="module")
def both_forms():
    model = loop_model()
    data = loop_record(model, 0, N=800)
    return model, {f: casest.filter_error_estimate(model, data, {"v": 0.1}, formulation=f)
                   for f in ("steady-state", "time-varying")}


def test_steady_state_estimate_within_three_std_of_the_truth(both_forms):
    model, fits = both_forms
    fe = fits["steady-state"]
    assert fe.success and fe.formulation == "steady-state", fe.notes
    truth = model.vector(LOOP_TRUTH)
    assert np.all(np.abs(fe.theta - truth) < 3 * fe.std), (fe.theta - truth) / fe.std
    assert abs(fe.process_noise["v"] - LOOP_Q) < 3 * fe.process_noise_std["v"]
    assert np.all(np.abs(fe.R - LOOP_NOISE**2) < 3 * fe.R_std)
    assert any("steady-state filter-error form" in n for n in fe.notes)


def test_the_steady_forms_record_is_its_own_filter(both_forms):
    """The gain, the innovations and their std the estimate holds are the DARE's filter at the
    estimate (NumPy, written out), and its own likelihood V is theirs."""
    model, fits = both_forms
    fe = fits["steady-state"]
    data = loop_record(model, 0, N=800)
    V, K, S, E = numpy_steady_filter(data, *fe.theta, fe.process_noise["v"], fe.R)
    record = fe.predictions
    np.testing.assert_allclose(fe.gain, K, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(record.kc_diagonal, np.diag(K), rtol=1e-8)  # C = I
    np.testing.assert_allclose(fe.innovations, E, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(record.innovation_std, np.tile(np.sqrt(np.diag(S)), (data.n_samples, 1)), rtol=1e-8)
    np.testing.assert_allclose(fe.cost, V, rtol=1e-10)
    assert record.gain_at == "the operating point"


def test_linear_model_forms_agree_within_their_std(both_forms):
    """A linear, time-invariant model: after the first samples the time-varying gain is the steady
    one, so the two estimates agree to a fraction of a std."""
    _, fits = both_forms
    steady, varying = fits["steady-state"], fits["time-varying"]
    assert varying.formulation == "time-varying"
    assert np.all(np.abs(steady.theta - varying.theta) < 0.3 * varying.std)


def test_steady_state_refuses_missing_samples_and_unknown_forms():
    model = loop_model()
    data = loop_record(model, 1, N=100)
    y1 = data.outputs[:, 0].copy()
    y1[5] = np.nan
    gappy = model.dataset({"t": data.signals[:, 0], "u": data.signals[:, 1], "y1": y1, "y2": data.outputs[:, 1]},
                          missing="allow")
    with pytest.raises(DataError, match="complete outputs"):
        casest.filter_error_estimate(model, gappy, {"v": 0.1}, formulation="steady-state")
    with pytest.raises(OptionError, match="formulation must be one of"):
        casest.filter_error_estimate(model, data, {"v": 0.1}, formulation="constant")


@pytest.mark.parametrize("formulation", ["steady-state", "time-varying"])
def test_scoring_reaches_the_exact_hessian_optimum(formulation):
    """Scoring (Fisher information, exact gradient) and IPOPT (exact Hessian) minimise the same V:
    the same optimum to 1e-8 relative in V and 1e-3 std in the parameters."""
    model = loop_model()
    data = loop_record(model, 2, N=500)
    fits = {s: casest.filter_error_estimate(model, data, {"v": 0.1}, formulation=formulation, solver=s)
            for s in ("scoring", "ipopt")}
    scoring, ipopt = fits["scoring"], fits["ipopt"]
    assert scoring.success and ipopt.success
    assert scoring.cost == pytest.approx(ipopt.cost, rel=1e-8)
    assert np.all(np.abs(scoring.theta - ipopt.theta) < 1e-3 * ipopt.std)
    fisher = casest.filter_error_estimate(model, data, {"v": 0.1}, formulation=formulation, covariance="fisher")
    # expected and observed information agree at the optimum to sampling error (within 30 %); a
    # parameter that scoring holds exactly on its bound has no std, with the bound as the reason
    inside = np.array([side is None for side in fisher.active_bounds])
    assert all(fisher.std_reason_codes[i] is StdReason.ACTIVE_BOUND for i in np.flatnonzero(~inside))
    np.testing.assert_allclose(fisher.std[inside], ipopt.std[inside], rtol=0.3)


@pytest.mark.slow
def test_a_noise_variance_at_its_floor_is_a_caution():
    """Truth: on this record (models/longitudinal.py, seed 1) the time-varying likelihood is maximal with
    R[a_z_m] at its floor (a_z is a combination of the gust-driven states), which leaves the a_z bias
    with a std near zero: the estimate must say so and not be trusted."""
    import os

    from casest.status import NoteCode, TrustCode

    mf = casest.load_model_file(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "models",
                                             "longitudinal.py"))
    fe = casest.filter_error_estimate(mf.model(), mf.simulate(1), {"u": 0.1, "w": 0.1})
    assert fe.success and fe.R[-1] < 1e-15
    assert NoteCode.NOISE_FLOOR in [getattr(n, "code", None) for n in fe.notes]
    code, reason = fe.conclusion()
    assert code is TrustCode.CAUTION and "floor" in reason


def test_the_iteration_count_sums_every_relinearisation_pass(monkeypatch):
    """The steady-state form reported the last pass's iterations ("iterations = 1" after four
    passes); it reports their sum (every pass's solve counted here by wrapping it)."""
    import casest.filter_error.likelihood as fem

    counted, original = [], fem._solve_nlp

    def counting(*args, **kwargs):
        run = original(*args, **kwargs)
        counted.append(run.iterations)
        return run

    monkeypatch.setattr(fem, "_solve_nlp", counting)
    from test_compiled_filters import THETA, pendulum

    model = pendulum()  # nonlinear: the gain moves with the reference point, so several passes
    rng = np.random.default_rng(1)
    t = np.arange(400) * 0.05
    torque = 0.5 * np.sin(1.3 * t)
    _, Y = model.simulate(THETA, model.dataset({"t": t, "torque": torque, "px": 0 * t, "py": 0 * t}))
    Y = Y + rng.normal(0.0, 0.05, Y.shape)
    data = model.dataset({"t": t, "torque": torque, "px": Y[:, 0], "py": Y[:, 1]})
    fit = casest.filter_error_estimate(model, data, {"rate": 0.1}, formulation="steady-state")
    assert len(counted) >= 2 and fit.n_iterations == sum(counted) > counted[-1]


def test_the_steady_forms_compiled_sensitivity_loop_equals_the_graphs_jacobian():
    """dE/dw and dS/dw of the steady-state graph (w = [theta; q; r]: the gain and S depend on all
    of them) by the compiled loop against CasADi's Jacobian of the graph, to 1e-10."""
    import casadi as ca

    from casest._casadi.numerics import compiler_available
    from casest.filter_error.gain_sensitivities import GainPassDerivatives, gain_pass_loop
    from casest.filter_error.scoring import InnovationDerivatives
    from casest.filter_error.steady import steady_cost_graph, steady_record_columns

    model = loop_model()
    data = loop_record(model, 2, N=200)
    graph = steady_cost_graph(model, data.n_samples)
    theta, q, r, D, last, d0 = graph.symbols
    w, p = ca.vertcat(theta, q, r), ca.vertcat(ca.vec(D), last, d0, *graph.point)
    loop = gain_pass_loop(model, w.numel())
    if not compiler_available() or loop[0] is None:
        pytest.skip("the loop needs a C compiler")
    compiled = GainPassDerivatives(model, w, p, graph.E, graph.S, *graph.gain_pass, loop, 0)
    reference = InnovationDerivatives(w, p, graph.E, graph.S)
    D_values, last_values = steady_record_columns(model, data)
    p_values = np.concatenate([D_values.reshape(-1, order="F"), last_values, model.initial_values(data),
                               np.zeros(2), data.signals[0, 1:], [LOOP_DT]])
    w_values = np.concatenate([[0.8, 3.5, 1.2], [0.0, 0.09], [2e-4, 6e-4]])
    for ours, expected in zip(compiled(w_values, p_values), reference(w_values, p_values)):
        assert ours.shape == expected.shape
        np.testing.assert_allclose(ours, expected, rtol=1e-10, atol=1e-10 * max(np.abs(expected).max(), 1e-300))
