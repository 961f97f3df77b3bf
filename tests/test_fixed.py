"""Fixed parameters: the estimate equals that of the model with the value substituted by hand.

Truth of the comparison: scalar example 2 (paper Eq. 33) with a = 1 written into the
expression, estimated on the same data (seed 0); agreement to 1e-8 relative.
"""

import casadi as ca
import numpy as np
import pytest

import casest

scalar2 = casest.load_model_file("scalar2")


@pytest.fixture(scope="module")
def by_hand():
    model, data = scalar2.model(), scalar2.simulate(0)
    b, c, d, eta = (ca.SX.sym(n) for n in ("b", "c", "d", "eta"))
    hand = casest.Model(list(model.parameters[1:]), [casest.Signal("eta", unit="rad")],
                        {"z": 2.0 * ca.cos(eta * (1 + b) + c) + d}, name="hand")
    ref = casest.estimate(hand, casest.Dataset(hand, {"eta": data.column("eta"), "z": data.column("z")}))
    return model, data, ref


def _check(est, ref):
    assert est.success and est.parameter_names == ("a", "b", "c", "d")
    assert est.theta[0] == 1.0 and np.isnan(est.std[0]) and "fixed at 1" in est.std_reasons[0]
    np.testing.assert_allclose(est.theta[1:], ref.theta, rtol=1e-8)
    np.testing.assert_allclose(est.std[1:], ref.std, rtol=1e-8)
    np.testing.assert_allclose(est.cost, ref.cost, rtol=1e-10)
    assert "trust it" in est.report().split("[[Conclusion]]")[1]  # a fixed parameter's missing std is by design


def test_fixed_by_argument(by_hand):
    model, data, ref = by_hand
    _check(casest.estimate(model, data, fixed={"a": 1.0}), ref)


def test_fixed_in_the_declaration(by_hand):
    model, data, ref = by_hand
    params = [casest.Parameter("a", nominal=1.0, fixed=True)] + list(model.parameters[1:])
    a, b, c, d, eta = (ca.SX.sym(n) for n in ("a", "b", "c", "d", "eta"))
    declared = casest.Model(params, [casest.Signal("eta", unit="rad")], {"z": (1 + a) * ca.cos(eta * (1 + b) + c) + d})
    _check(casest.estimate(declared, casest.Dataset(declared, {"eta": data.column("eta"), "z": data.column("z")})), ref)


def test_fixed_value_errors(by_hand):
    model, data, _ = by_hand
    with pytest.raises(casest.ModelError, match=r"fixed value b = 2.0 must be finite and inside \[0.0, 0.5\]"):
        casest.estimate(model, data, fixed={"b": 2.0})
    with pytest.raises(casest.ModelError, match="unknown parameter 'e'"):
        casest.estimate(model, data, fixed={"e": 0.0})


def test_fixed_on_the_command_line(capsys):
    from casest.apps.cli import main

    assert main(["solve", "scalar2", "--fix", "a=1.0", "--quick"]) == 0
    assert "a = 1 +/- n/a" in capsys.readouterr().out
    assert main(["solve", "scalar2", "--fix", "a:1"]) == 2
