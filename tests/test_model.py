"""Model declaration: symbols matched by name, and errors that name the problem."""

import casadi as ca
import numpy as np
import pytest

from casest import Gaussian, LogUniform, Model, ModelError, Parameter, Signal, Uniform

a, b, x = ca.SX.sym("a"), ca.SX.sym("b"), ca.SX.sym("x")


def test_symbols_matched_by_name_and_predict():
    m = Model([Parameter("a"), Parameter("b", 0, 1, 0.5)], [Signal("x")], {"z": a * x + b})
    assert m.parameter_names == ("a", "b")
    np.testing.assert_allclose(m.predict({"a": 2.0, "b": 0.5}, np.array([[1.0], [3.0]]))[:, 0], [2.5, 6.5])


def test_mx_expression_is_expanded():
    am, xm = ca.MX.sym("a"), ca.MX.sym("x")
    m = Model([Parameter("a")], ["x"], {"z": am * ca.sin(xm)})
    assert isinstance(m.h, ca.SX)
    np.testing.assert_allclose(m.predict([2.0], np.array([[0.5]])), [[2 * np.sin(0.5)]])


def test_undeclared_symbol_is_named_with_hint():
    bb = ca.SX.sym("bb")
    with pytest.raises(ModelError, match=r"'bb' \(did you mean 'b'\?\)"):
        Model([Parameter("a"), Parameter("b")], ["x"], {"z": a * x + b + bb})


def test_parameter_that_appears_nowhere():
    with pytest.raises(ModelError, match=r"\['b'\] appear in no output"):
        Model([Parameter("a"), Parameter("b")], ["x"], {"z": a * x})


def test_lb_greater_than_ub():
    with pytest.raises(ModelError, match=r"'a': lower bound 2.0 > upper bound 1.0"):
        Model([Parameter("a", lb=2.0, ub=1.0, nominal=1.5)], ["x"], {"z": a * x})


def test_duplicate_names():
    with pytest.raises(ModelError, match="duplicate name 'a'"):
        Model([Parameter("a"), Parameter("a")], ["x"], {"z": a * x})
    with pytest.raises(ModelError, match="duplicate name 'x'"):
        Model([Parameter("x")], ["x"], {"z": x})


def test_nominal_outside_bounds():
    with pytest.raises(ModelError, match="nominal value 5.0 lies outside"):
        Model([Parameter("a", 0, 1, nominal=5.0)], ["x"], {"z": a * x})


def test_a_vector_valued_output_is_one_channel_per_entry():
    """Issue 28: vector outputs (and Functions with a vector output) are accepted as channels
    z_0, z_1, ... (column-major, the naming of vector symbols), each with the entry's unit.
    Truth: the same model written channel by channel."""
    rotate = ca.Function("rotate", [a, x], [ca.vertcat(a * ca.cos(x), a * ca.sin(x))], ["a", "x"], ["v"])
    for outputs in ({"z": ca.vertcat(a * ca.cos(x), a * ca.sin(x))}, {"z": rotate}):
        m = Model([Parameter("a")], ["x"], outputs, output_units={"z": "m/s"})
        assert m.output_names == ("z_0", "z_1") and m.output_units == ("m/s", "m/s")
        by_channel = Model([Parameter("a")], ["x"], {"z_0": a * ca.cos(x), "z_1": a * ca.sin(x)})
        X = np.array([[0.1], [0.7], [2.0]])
        np.testing.assert_array_equal(m.predict(np.array([1.5]), X), by_channel.predict(np.array([1.5]), X))
    with pytest.raises(ModelError, match="is empty"):
        Model([Parameter("a")], ["x"], {"z": a * x, "w": ca.SX(0, 1)})


def test_prior_checks():
    with pytest.raises(ModelError, match="Uniform prior needs finite bounds"):
        Model([Parameter("a", prior=Uniform())], ["x"], {"z": a * x})
    with pytest.raises(ModelError, match="LogUniform"):
        Model([Parameter("a", -1, 1, prior=LogUniform())], ["x"], {"z": a * x})
    with pytest.raises(ModelError, match="no probability mass"):
        Model([Parameter("a", 0, 1, 0.5, prior=Gaussian(100.0, 0.01))], ["x"], {"z": a * x})


def test_priors_quantiles_stay_in_bounds():
    u = np.linspace(0, 1, 11)
    g = Gaussian(0.0, 1.0).ppf(u, -0.5, 2.0)
    assert g.min() >= -0.5 and g.max() <= 2.0 and np.all(np.diff(g) >= 0)
    lu = LogUniform().ppf(u, 0.01, 100.0)
    np.testing.assert_allclose(lu[[0, 5, 10]], [0.01, 1.0, 100.0])


def test_a_box_over_more_than_a_decade_is_sampled_log_uniformly_by_default():
    """The default sampling prior of a finite box: log-uniform when it has one sign and spans at
    least LOG_SPAN (a decade), uniform otherwise; the NLP's scale stays the uniform spread."""
    from casest.models.priors import LOG_SPAN

    assert LOG_SPAN == 10.0
    assert isinstance(Parameter("k", 1e-3, 10.0).sampling_prior, LogUniform)
    assert isinstance(Parameter("k", -500.0, -0.5).sampling_prior, LogUniform)
    assert isinstance(Parameter("k", 1.0, 9.99).sampling_prior, Uniform)
    assert isinstance(Parameter("k", -1.0, 100.0).sampling_prior, Uniform)  # contains 0
    assert isinstance(Parameter("k", 1e-3, 10.0, prior=Uniform()).sampling_prior, Uniform)  # declared wins
    wide = Parameter("k", 1e-3, 10.0)
    assert wide.typical_scale == Parameter("k", 1e-3, 10.0, prior=Uniform()).typical_scale
    assert isinstance(wide.declared_prior, Uniform)
    # half the draws of a log-uniform box over five decades lie below its geometric mean (0.1)
    u = np.linspace(0.0, 1.0, 101)
    assert np.count_nonzero(wide.sampling_prior.ppf(u, wide.lb, wide.ub) < 0.1) == 50


def test_unknown_parameter_name_in_vector():
    m = Model([Parameter("a")], ["x"], {"z": a * x})
    with pytest.raises(ModelError, match=r"unknown parameter 'aa' \(did you mean 'a'\?\)"):
        m.vector({"aa": 1.0})
