"""The record loop (one compiled C function over a whole record) against CasADi's ``mapaccum``.

Truth: CasADi's own evaluation of the same step over the same rows (its virtual machine),
exactly (the loop is compiled without fused multiply-adds or fast-math).
"""

import casadi as ca
import numpy as np
import pytest

from casest._casadi.numerics import compiler_available
from casest._casadi.record_loop import RecordLoop, split_step
from casest.filters.compiled_passes import run_record

pytestmark = pytest.mark.skipif(not compiler_available(), reason="needs a C compiler")


def _sparse_step() -> ca.Function:
    acc, d, c = ca.SX.sym("acc", 2), ca.SX.sym("d", 2), ca.SX.sym("c", 1)
    record = ca.vertcat(acc[0] * d[0], ca.SX(1, 1), ca.sin(acc[1]) + d[1] * c)  # a structural zero
    return ca.Function("sparse_step", [acc, d, c], [ca.vertcat(0.5 * acc[1] + c, ca.cos(acc[0]) + d[0]), record])


def test_a_step_with_sparse_outputs_runs_as_its_dense_record():
    step = _sparse_step()
    assert not step.sparsity_out(1).is_dense()
    D = np.column_stack([np.linspace(0.0, 1.0, 300), np.cos(np.arange(300.0))])
    acc0, c = np.array([1.0, 2.0]), np.array([0.3])
    accs_vm, (rec_vm,) = run_record(step, acc0, D, c, compiled=False, widths=(3,))
    loop = RecordLoop.build(step)
    assert loop is not None
    accs_c, (rec_c,) = loop(acc0, D, c)
    np.testing.assert_array_equal(accs_c, accs_vm)
    np.testing.assert_array_equal(rec_c, rec_vm)
    assert accs_vm.shape == (301, 2) and rec_vm.shape == (300, 3) and not rec_vm[:, 1].any()
    np.testing.assert_array_equal(accs_c[0], acc0)


def test_the_record_splits_into_contiguous_fields():
    step = _sparse_step()
    D = np.random.default_rng(0).standard_normal((50, 2))
    accs, fields = run_record(step, np.ones(2), D, np.array([0.1]), compiled=True, widths=(1, 2))
    assert [f.shape for f in fields] == [(50, 1), (50, 2)] and all(f.flags.c_contiguous for f in fields)
    _, (whole,) = run_record(step, np.ones(2), D, np.array([0.1]), compiled=False, widths=(3,))
    np.testing.assert_array_equal(np.hstack(fields), whole)
    with pytest.raises(ValueError, match="fields of 4 entries for a record of 3"):
        split_step(step, (2, 2))


def test_a_step_without_a_record_or_constants():
    acc, d = ca.SX.sym("acc", 1), ca.SX.sym("d", 1)
    step = ca.Function("decay", [acc, d], [0.9 * acc + d])
    D = np.ones((10, 1))
    accs, fields = RecordLoop.build(step)(np.array([0.0]), D)
    expected = [0.0]
    for _ in range(10):
        expected.append(0.9 * expected[-1] + 1.0)
    np.testing.assert_allclose(accs[:, 0], expected, rtol=1e-15)
    assert fields == []


@pytest.mark.parametrize("n_samples", [1, 2, 301])
def test_keeping_only_the_last_accumulator(n_samples):
    # a pass whose record holds what it needs writes two accumulator rows in turn: the fields and
    # the final accumulator are those of the pass that keeps every row (odd and even N)
    step = _sparse_step()
    D = np.random.default_rng(n_samples).standard_normal((n_samples, 2))
    loop = RecordLoop.build(step)
    acc0, c = np.array([0.5, -1.0]), np.array([0.2])
    accs, (kept,) = loop(acc0, D, c)
    last, (fields,) = loop(acc0, D, c, keep_accumulators=False)
    assert last.shape == (1, 2)
    np.testing.assert_array_equal(last[0], accs[-1])
    np.testing.assert_array_equal(fields, kept)
