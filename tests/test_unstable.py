"""An open-loop unstable aircraft (models/unstable.py): output error by multiple shooting.

Truth: the closed-loop flight simulated by the exact discretisation with a fixed seed; the
open-loop model diverges at 1.1 rad/s. From the model file's start (derivatives 20-50 %
off), multiple shooting with nodes started from the measured outputs reaches an optimum at
or below the truth's cost with every parameter within 3 std of the truth; single shooting
from the same start does not (the simulation's growth over 12 s is e^13).
"""

import os
import warnings

import numpy as np

import casest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_multiple_shooting_recovers_an_unstable_aircraft_where_single_shooting_does_not():
    mf = casest.load_model_file(os.path.join(REPO, "models", "unstable.py"))
    model, data = mf.model(), mf.simulate(0)
    truth = model.vector(mf.TRUTH)
    problem = casest.Problem(model, data)
    multiple = casest.SolverSettings(shooting="multiple", shooting_interval=25)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        est = casest.estimate(model, data, start=mf.START, mode="full", solver_settings=multiple)
        single = casest.solve_stage2(model, data, model.vector(mf.START), mode="full",
                                     settings=casest.SolverSettings(max_iter=300))
    assert est.success
    assert est.cost <= problem.profile_cost(truth)
    z = (est.theta - truth) / est.std
    assert np.all(np.abs(z) < 3), dict(zip(model.parameter_names, z.round(2)))
    assert not single.success or single.cost > est.cost + 100
    eigenvalues = np.linalg.eigvals([[mf.TRUTH["Z_alpha"], 1.0], [mf.TRUTH["M_alpha"], mf.TRUTH["M_q"]]])
    assert eigenvalues.real.max() > 1.0  # the case is what it claims: open-loop unstable


def test_artificial_stabilisation_recovers_the_unstable_aircraft_beside_multiple_shooting():
    """Output error on the model stabilised by the measured alpha and q fed back with gain 1.3
    (A - K C stable; the textbook's artificial stabilisation) from the model file's start, where
    single shooting of the open-loop model stalls (the test above): converged, every parameter
    within 3 std of the simulated truth and within 1.5 std of the multiple-shooting estimate of
    the same record (the fed-back noise biases it slightly, about one std on M_delta)."""
    mf = casest.load_model_file(os.path.join(REPO, "models", "unstable.py"))
    model, data = mf.model(), mf.simulate(1)
    truth = model.vector(mf.TRUTH)
    gain = np.diag([1.3, 1.3])
    A = np.array([[mf.TRUTH["Z_alpha"], 1.0], [mf.TRUTH["M_alpha"], mf.TRUTH["M_q"]]])
    assert np.linalg.eigvals(A - gain).real.max() < 0  # the gain stabilises the truth
    stabilised = casest.artificially_stabilised(model, gain)
    assert stabilised.signal_names[-2:] == ("fed_back_alpha_m", "fed_back_q_m")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        est = casest.estimate(stabilised, casest.stabilised_dataset(stabilised, data), start=mf.START, mode="full")
        multiple = casest.estimate(model, data, start=mf.START, mode="full",
                                   solver_settings=casest.SolverSettings(shooting="multiple", shooting_interval=25))
    assert est.success and multiple.success
    assert np.all(np.abs(est.theta - truth) < 3 * est.std), (est.theta - truth) / est.std
    assert np.all(np.abs(est.theta - multiple.theta) < 1.5 * multiple.std), (est.theta - multiple.theta) / multiple.std


def test_a_stabilising_gain_of_the_wrong_shape_is_refused():
    mf = casest.load_model_file(os.path.join(REPO, "models", "unstable.py"))
    model = mf.model()
    import pytest

    with pytest.raises(casest.ModelError, match=r"shape \(n_states, n_outputs\) = \(2, 2\)"):
        casest.artificially_stabilised(model, np.eye(3))
    with pytest.raises(casest.ModelError, match="not all zero"):
        casest.artificially_stabilised(model, np.zeros((2, 2)))


def test_a_gain_that_does_not_stabilise_is_said_and_wrong_types_are_named():
    """Truth: with the model file's nominal parameters A has an eigenvalue of positive real part
    (the case is unstable); -5 I adds 5 to every eigenvalue of A - K C, so it stays unstable and
    casest must say so; 1.3 I is the textbook's stabilising gain of the test above."""
    import pytest

    mf = casest.load_model_file(os.path.join(REPO, "models", "unstable.py"))
    model = mf.model()
    with pytest.warns(RuntimeWarning, match="leaves A - K C unstable"):
        casest.artificially_stabilised(model, -5 * np.eye(2))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        stabilised = casest.artificially_stabilised(model, np.diag([1.3, 1.3]))
    with pytest.raises(casest.OptionError, match="takes a casest.DynamicModel"):
        casest.artificially_stabilised(casest.load_model_file("scalar2").model(), np.eye(1))
    with pytest.raises(casest.OptionError, match="stabilised_dataset takes"):
        casest.stabilised_dataset(stabilised, {"t": [0.0]})
