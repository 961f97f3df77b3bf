"""The record loop (one compiled C function over a whole record) against CasADi's ``mapaccum``.

Truth: CasADi's own evaluation of the same step over the same rows (its virtual machine),
exactly (the loop is compiled without fused multiply-adds or fast-math).
"""

import casadi as ca
import numpy as np
import pytest

from casest._casadi.numerics import compiler_available
from casest._casadi.record_loop import RecordLoop, RecordRows, split_step
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


def _row_echo_step(n_outputs: int, n_inputs: int) -> ca.Function:
    """A step whose record is the row it read and whose accumulator counts the rows."""
    acc, d = ca.SX.sym("acc", 1), ca.SX.sym("d", 2 * n_outputs + 3 * n_inputs + 1)
    return ca.Function("row_echo", [acc, d], [acc + 1, d])


@pytest.mark.parametrize("n_samples", [1, 2, 57])
def test_a_loop_builds_a_filters_rows_from_the_record_itself(n_samples):
    # truth: the same rows built in NumPy (RecordRows.columns), and by hand for the last sample
    rng = np.random.default_rng(7 + n_samples)
    Y = rng.standard_normal((n_samples, 3))
    Y[rng.random(Y.shape) < 0.3] = np.nan
    Y[0, 1] = np.inf  # not finite: not measured, as NaN
    t = np.cumsum(rng.uniform(0.01, 0.1, n_samples))
    signals = np.column_stack([t, rng.standard_normal((n_samples, 2))])
    rows = RecordRows(Y, signals)
    loop = RecordLoop.build(_row_echo_step(3, 2), signal_rows=(3, 2))
    accs, (echo,) = loop(np.zeros(1), rows)
    D = rows.columns()
    np.testing.assert_array_equal(echo, D)
    np.testing.assert_array_equal(accs[:, 0], np.arange(n_samples + 1))
    last = D[-1]
    np.testing.assert_array_equal(last[:3], np.where(np.isfinite(Y[-1]), Y[-1], 0.0))
    np.testing.assert_array_equal(last[3:6], np.isfinite(Y[-1]))
    np.testing.assert_array_equal(last[6:8], signals[-1, 1:])
    assert not last[8:].any()  # the last sample's interval inputs and step
    if n_samples > 1:
        np.testing.assert_array_equal(D[0, 8:10], signals[0, 1:])
        np.testing.assert_array_equal(D[0, 10:12], signals[1, 1:])
        assert D[0, 12] == t[1] - t[0]
    # written into an earlier call's arrays, the same
    again = loop(np.zeros(1), rows, out=(accs, [echo]))
    np.testing.assert_array_equal(again[1][0], D)


def test_record_rows_need_a_loop_built_for_them_and_their_shapes():
    rows = RecordRows(np.zeros((5, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="build it with signal_rows"):
        RecordLoop.build(_row_echo_step(3, 2))(np.zeros(1), rows)
    loop = RecordLoop.build(_row_echo_step(3, 2), signal_rows=(3, 2))
    with pytest.raises(ValueError, match=r"outputs of shape \(N, 3\) and signals of shape \(N, 3\)"):
        loop(np.zeros(1), RecordRows(np.zeros((5, 2)), np.zeros((5, 3))))
    with pytest.raises(ValueError, match="not those of 2 outputs and 2 inputs"):
        RecordLoop.build(_row_echo_step(3, 2), signal_rows=(2, 2))
