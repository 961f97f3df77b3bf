"""Per-sample functions over a record in blocks (casest._casadi.sample_blocks.evaluate_samples).

Expected values: the same function mapped over the whole record by CasADi's own ``map`` (the
evaluation the blocks replace), to the bit.
"""

import casadi as ca
import numpy as np
import pytest

from casest._casadi.sample_blocks import BLOCK, evaluate_samples


def probe():
    x, z, p = ca.SX.sym("x", 2), ca.SX.sym("z"), ca.SX.sym("p", 3)
    h = ca.vertcat(p[0] * ca.sin(p[1] * x[0]) + x[1], p[2] * z * x[0])
    # a sparse Jacobian (d h / d p has structural zeros) as a matrix output
    return ca.Function("probe", [x, z, p], [h, ca.jacobian(h, p)], ["x", "z", "p"], ["h", "dh_dp"])


@pytest.mark.parametrize("n_samples", [1, 7, BLOCK, 2 * BLOCK + 5])
def test_blocks_equal_a_map_over_the_whole_record(n_samples):
    f = probe()
    rng = np.random.default_rng(n_samples)
    X, Z, p = rng.standard_normal((n_samples, 2)), rng.standard_normal((n_samples, 1)), rng.standard_normal(3)
    h, J = evaluate_samples(f, [X, Z], [p])
    assert h.shape == (n_samples, 2) and J.shape == (n_samples, 6)
    h_map, J_map = f.map(n_samples)(X.T, Z.T, p)
    np.testing.assert_array_equal(h, np.asarray(h_map).T)
    # each sample's 2 x 3 Jacobian, column-major in its row
    J_map = np.asarray(ca.densify(J_map)).reshape(2, n_samples, 3).transpose(1, 2, 0).reshape(n_samples, 6)
    np.testing.assert_array_equal(J, J_map)


def test_wrong_sizes_are_named():
    f = probe()
    with pytest.raises(ValueError, match="input p needs 3 values"):
        evaluate_samples(f, [np.zeros((4, 2)), np.zeros((4, 1))], [np.zeros(2)])
    with pytest.raises(ValueError, match="input z needs 4 values"):
        evaluate_samples(f, [np.zeros((4, 2)), np.zeros((5, 1))], [np.zeros(3)])
