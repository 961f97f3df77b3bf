"""The NumPy evaluation of stage 1 below the compile threshold (casest/backend/array_sums.py)
against CasADi's own evaluation of the same function: every operation, values that depend on the
data or on the candidate only, NaN and infinity, operations with no NumPy form, and the sweep's
results against CasADi's map-reduce on NIST problems."""

import importlib

import casadi as ca
import numpy as np

import casest
from casest.apps.nist import read_nist
from casest.backend.array_sums import ArraySum, ArrayValues
from casest.problem.separate import separate

from test_lane_sums import _every_operation, _reference

evaluators = importlib.import_module("casest.two_stage.sweep.evaluators")


def test_every_operation_matches_casadi():
    # reference: CasADi's own evaluation; NumPy's sums are pairwise, CasADi's in sample order
    fun = _every_operation()
    rng = np.random.default_rng(0)
    X, P = rng.uniform(0.1, 2.0, (333, 2)), rng.uniform(0.5, 1.5, (7, 2))
    summed = ArraySum.build(fun, [X])
    assert summed is not None
    summed.block = 2  # several blocks of candidates, the last one short
    got, ref = summed(P), _reference(fun, X, P)
    assert got.shape == ref.shape == (7, fun.nnz_out(0))
    np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-13)


def test_values_at_every_sample_match_casadi():
    fun = _every_operation()
    rng = np.random.default_rng(1)
    X, P = rng.uniform(0.1, 2.0, (40, 2)), rng.uniform(0.5, 1.5, (5, 2))
    values = ArrayValues.build(fun, [X])(P)
    assert values.shape == (5, 40, fun.nnz_out(0))
    for m, q in enumerate(P):
        ref = np.asarray(fun.map(40)(X.T, np.tile(q[:, None], (1, 40)))).T
        np.testing.assert_allclose(values[m], ref, rtol=1e-14, atol=1e-14)


def test_entries_of_the_data_or_the_candidate_only_are_summed_over_every_sample():
    # x only, p only, a constant and their product: each summed over N = 6 samples
    x, p = ca.SX.sym("x"), ca.SX.sym("p")
    fun = ca.Function("f", [x, p], [ca.vertcat(x ** 2, ca.sin(p), ca.SX(3.0), x * p)])
    X, P = np.arange(1.0, 7.0)[:, None], np.array([[0.5], [2.0], [-1.0]])
    got = ArraySum.build(fun, [X])(P)
    expected = np.column_stack([np.full(3, np.sum(X ** 2)), 6 * np.sin(P[:, 0]), np.full(3, 18.0), 21.0 * P[:, 0]])
    np.testing.assert_allclose(got, expected, rtol=1e-15)


def test_nan_and_inf_reach_the_sums():
    x, p = ca.SX.sym("x"), ca.SX.sym("p")
    fun = ca.Function("f", [x, p], [ca.vertcat(ca.log(x - p), 1 / (x - p))])
    out = ArraySum.build(fun, [np.array([[1.0], [2.0], [3.0]])])(np.array([[0.0], [2.0], [5.0]]))
    assert np.isfinite(out[0]).all()
    assert not np.isfinite(out[1]).any() and np.isnan(out[2, 0])


def test_operations_without_a_numpy_form_keep_casadis_path():
    x, p = ca.SX.sym("x"), ca.SX.sym("p")
    inner = ca.Function("inner", [x], [x ** 2], {"never_inline": True})
    assert ArraySum.build(ca.Function("outer", [x, p], [inner(x) * p]), [np.ones((3, 1))]) is None
    sparse = ca.Function("sparse", [x, p], [ca.vertcat(x * p, ca.SX(1, 1))])
    assert ArraySum.build(sparse, [np.ones((3, 1))]) is None
    X, Y = ca.MX.sym("x"), ca.MX.sym("p")
    assert ArraySum.build(ca.Function("mx", [X, Y], [X * Y]), [np.ones((3, 1))]) is None


def _map_reduce_evaluator(partition, data, n, monkeypatch):
    """The same evaluator on CasADi's map-reduce (the path the array evaluation replaced)."""
    with monkeypatch.context() as patch:
        patch.setattr(ArraySum, "build", classmethod(lambda cls, *a, **k: None))
        return evaluators.GramEvaluator(partition, data, n, jit=False, threads=1)


def test_nist_sweeps_equal_casadis_map_reduce(monkeypatch):
    # reference: CasADi's map-reduce of the same Gram function. The Gram sums agree to the last bits
    # (relative to sqrt(G_ii G_jj)); the normal equations amplify those bits by the basis' condition
    # number (up to SweepSettings.condition_limit = 1e10), hence the looser tolerance of R and xi1,
    # looser still for Lanczos3's nearly collinear exponentials
    for name, rtol in (("Misra1a", 1e-6), ("Thurber", 1e-6), ("MGH09", 1e-6), ("Lanczos3", 1e-4)):
        problem = read_nist(f"data/nist_strd/{name}.dat", start=1)
        partition = separate(problem.model)
        rng = np.random.default_rng(2)
        index = list(partition.nonlinear_index)
        lb, ub, nominal = (problem.model.lower_bounds[index], problem.model.upper_bounds[index],
                           problem.model.nominal[index])
        lo, hi = np.maximum(lb, nominal - np.abs(nominal)), np.minimum(ub, nominal + np.abs(nominal))
        cands = rng.uniform(lo, hi, (300, partition.n_nonlinear))
        fast = evaluators.GramEvaluator(partition, problem.data, 300, jit=False, threads=2)
        assert isinstance(fast._lanes, ArraySum), name
        slow = _map_reduce_evaluator(partition, problem.data, 300, monkeypatch)
        G_f, G_s = fast.gram(cands), slow.gram(cands)
        d = np.sqrt(np.abs(np.diagonal(G_s, axis1=2, axis2=3)))
        finite = np.isfinite(G_s).all(axis=(1, 2, 3))
        scaled = np.abs(G_f - G_s)[finite] / (d[..., :, None] * d[..., None, :])[finite]
        assert scaled.max() < 1e-13, name
        xi1_f, R_f, ok_f = fast.solve(cands)
        xi1_s, R_s, ok_s = slow.solve(cands)
        np.testing.assert_array_equal(ok_f, ok_s)
        np.testing.assert_allclose(R_f[ok_f], R_s[ok_s], rtol=rtol)
        np.testing.assert_allclose(xi1_f[ok_f], xi1_s[ok_s], rtol=rtol, atol=1e-8)


def test_bulk_values_equal_casadis_map():
    problem = read_nist("data/nist_strd/Thurber.dat", start=1)
    partition = separate(problem.model)
    bulk = evaluators.BulkEvaluator(partition, problem.data, 64.0, 50, jit=False)
    assert isinstance(bulk._lanes, ArrayValues)
    cands = np.tile(problem.model.nominal[list(partition.nonlinear_index)], (50, 1)) * np.linspace(0.9, 1.1, 50)[:, None]
    A, b = bulk(cands)
    for m in (0, 17, 49):
        x = ca.DM(cands[m])
        A_ref = np.vstack([np.asarray(partition.A(problem.data.signals[k], x)) for k in range(problem.data.n_samples)])
        b_ref = np.concatenate([np.asarray(partition.b(problem.data.signals[k], x)).ravel()
                                for k in range(problem.data.n_samples)])
        np.testing.assert_allclose(A[m], A_ref, rtol=1e-14)
        np.testing.assert_allclose(b[m], b_ref, rtol=1e-14, atol=1e-300)


def test_the_sweeps_symbolic_builds_are_kept_on_the_split_for_other_data():
    # the second evaluator of the same split reuses the first's functions (nothing rebuilt) and, on
    # other data of the same shape, gives the sums a fresh build gives (analytic: same function, same data)
    import pickle

    problem = read_nist("data/nist_strd/Misra1a.dat", start=1)
    partition = separate(problem.model)
    first = evaluators.GramEvaluator(partition, problem.data, 20, jit=False)
    other = casest.Dataset.from_arrays(problem.model, problem.data.signals, 2.0 * problem.data.outputs)
    second = evaluators.GramEvaluator(partition, other, 20, jit=False)
    assert second._program is first._program
    cands = np.linspace(1e-4, 1e-3, 20)[:, None]
    fresh_partition = pickle.loads(pickle.dumps(partition))
    assert len(fresh_partition.builds) == 0 and len(partition.builds) > 0  # a copy in another process builds anew
    fresh = evaluators.GramEvaluator(fresh_partition, other, 20, jit=False)
    assert fresh._program is not first._program
    np.testing.assert_array_equal(second.gram(cands), fresh.gram(cands))
    assert not np.allclose(first.gram(cands), second.gram(cands))


def test_candidate_only_values_equal_casadis_map():
    # reference: CasADi's map of the same candidate-only function (same operations, so to rounding)
    problem = read_nist("data/nist_strd/Gauss1.dat", start=1)
    partition = separate(problem.model)
    program = evaluators.GramEvaluator(partition, problem.data, 300, jit=False)._program
    nominal = problem.model.nominal[list(partition.nonlinear_index)]
    cands = nominal * np.random.default_rng(3).uniform(0.5, 1.5, (300, len(nominal)))
    expected = np.asarray(program.constants.map(300)(cands.T), dtype=float).reshape(-1, 300).T
    got = program.candidate_constants(cands)
    assert got.shape == (300, program.n_constants) and program.n_constants >= 2
    np.testing.assert_allclose(got, expected, rtol=1e-15, atol=0)
    assert program.candidate_constants(cands[:0]).shape == (0, program.n_constants)
