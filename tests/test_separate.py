"""Automatic separator: expected partitions are worked out by hand from each model's algebra."""

import casadi as ca
import numpy as np
import pytest

from casest import Model, Parameter, SeparationError, separate

S = {n: ca.SX.sym(n) for n in "a b c d e p q x y".split()}


def model(params, outputs, signals=("x",)):
    return Model([Parameter(n) for n in params], list(signals), outputs)


def test_scalar1_paper_eq22(scalar1):
    part = separate(scalar1.model())
    assert part.linear == ("a", "c") and part.nonlinear == ("b",)
    assert part.alternatives == ()


def test_scalar2_paper_eq34(scalar2):
    part = separate(scalar2.model())
    assert part.linear == ("a", "d") and part.nonlinear == ("b", "c")


def test_product_of_two_parameters_is_a_tie():
    a, b, c, x = S["a"], S["b"], S["c"], S["x"]
    part = separate(model("abc", {"z": a * b * x + c}))
    # a*b: either a or b can be linear, never both; c is linear in any case
    assert part.linear == ("a", "c") and part.nonlinear == ("b",)
    assert part.alternatives == (("b", "c"),)


def test_parameter_inside_vector_output():
    # 2-D rotation by angle e with scale a and offsets c, d: a rotation angle is nonlinear
    a, c, d, e, x, y = (S[n] for n in "acdexy")
    out = {
        "u": a * (ca.cos(e) * x - ca.sin(e) * y) + c,
        "v": a * (ca.sin(e) * x + ca.cos(e) * y) + d,
    }
    part = separate(model("acde", out, signals=("x", "y")))
    assert part.linear == ("a", "c", "d") and part.nonlinear == ("e",)
    assert part.A.size_out(0) == (2, 3)


def test_all_linear_model():
    a, b, c, x = S["a"], S["b"], S["c"], S["x"]
    part = separate(model("abc", {"z": a + b * x + c * x**2}))
    assert part.linear == ("a", "b", "c") and part.nonlinear == ()


def test_no_linear_parameter():
    a, b, x = S["a"], S["b"], S["x"]
    part = separate(model("ab", {"z": ca.exp(-a * x) + ca.sin(b**2 * x)}))
    assert part.linear == () and part.nonlinear == ("a", "b")


def test_pinning_to_either_side():
    a, b, c, x = S["a"], S["b"], S["c"], S["x"]
    m = model("abc", {"z": a * b * x + c})
    assert separate(m, linear=["b"]).linear == ("b", "c")
    assert separate(m, nonlinear=["c"]).nonlinear == ("b", "c")
    with pytest.raises(SeparationError, match="'a' and 'b' are both pinned"):
        separate(m, linear=["a", "b"])
    with pytest.raises(SeparationError, match="pinned both"):
        separate(m, linear=["a"], nonlinear=["a"])


def test_pinning_a_nonlinear_parameter_to_xi1_is_refused():
    a, b, x = S["a"], S["b"], S["x"]
    with pytest.raises(SeparationError, match="'b' is pinned to xi1 but the model is nonlinear in it"):
        separate(model("ab", {"z": a * x + ca.exp(b * x)}), linear=["b"])


def test_fabs_counts_as_nonlinear():
    a, b, x = S["a"], S["b"], S["x"]
    part = separate(model("ab", {"z": a * x + ca.fabs(b) * x}))
    assert part.linear == ("a",) and part.nonlinear == ("b",)


def test_a_and_b_reproduce_h_at_random_points():
    a, b, c, d, x, y = (S[n] for n in "abcdxy")
    m = model("abcd", {"u": (1 + a) * ca.cos(x * (1 + b) + c) + d * y, "v": a * y + ca.exp(b) * d}, ("x", "y"))
    part = separate(m)
    rng = np.random.default_rng(1)
    for _ in range(10):
        sig, theta = rng.normal(size=2), rng.normal(size=4)
        xi1, xi2 = theta[list(part.linear_index)], theta[list(part.nonlinear_index)]
        h = np.array(m.function(sig, theta)).ravel()
        recon = np.array(part.A(sig, xi2)) @ xi1 + np.array(part.b(sig, xi2)).ravel()
        np.testing.assert_allclose(recon, h, rtol=1e-12, atol=1e-12)
