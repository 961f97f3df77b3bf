"""The sweep's normal equations in C (casest.backend.gram_solve) against the NumPy path they replace.

Truth: GramEvaluator.solve with the compiled loop switched off (the NumPy normal equations, with
eigvalsh deciding the conditioning), and for the solved values numpy.linalg.lstsq on A itself.
Tolerances: the normal equations' own rounding, about cond(P) eps relative to y'y.
"""

import numpy as np
import pytest

import casest
from casest.backend.gram_solve import ACCURATE, NOT_A_FIT, RESOLVE, UNDECIDED, gram_solver
from casest.backend.sums import compiler_available
from casest.two_stage.sweep import draw_candidates
from casest.two_stage.sweep.evaluators import GramEvaluator
from casest.two_stage.sweep.orchestration import linear_parameter_bounds

needs_compiler = pytest.mark.skipif(not compiler_available(), reason="no C compiler")


def _triangles(G: np.ndarray) -> np.ndarray:
    """The upper triangles of Gram matrices (M, ny, n, n), channel after channel: (M, ny * T)."""
    rows, cols = np.triu_indices(G.shape[-1])
    return G[:, :, rows, cols].reshape(G.shape[0], -1)


@needs_compiler
def test_each_status_where_the_numpy_path_decides_the_same():
    """Hand-made Gram matrices of [A, y]: a well-posed fit (solved; x equals lstsq), an exact fit (RSS below
    1e-8 y'y: solved again from A), a zero column and a non-finite sum (not fits), and a nearly dependent
    pair of columns beyond the screen (left to eigvalsh)."""
    rng = np.random.default_rng(11)
    A = rng.normal(size=(4, 40, 3))
    y = rng.normal(size=(4, 40))
    y[1] = A[1] @ np.array([1.0, -2.0, 0.5])  # exact fit
    A[2, :, 1] = 0.0  # a zero column
    A[3, :, 2] = A[3, :, 1] * (1 + 1e-7)  # nearly dependent: condition ~1e15
    B = np.concatenate([A, y[:, :, None]], axis=2)
    G = np.einsum("mki,mkj->mij", B, B)[:, None]
    flat = _triangles(G)
    flat = np.vstack([flat, np.full((1, flat.shape[1]), np.nan)])
    solver = gram_solver(3, 1e10, cached_only=False)
    x, rss, status = solver(flat, 1, 3, 1e10)
    assert status.tolist() == [ACCURATE, RESOLVE, NOT_A_FIT, UNDECIDED, NOT_A_FIT]
    expected = np.linalg.lstsq(A[0], y[0], rcond=None)
    np.testing.assert_allclose(x[0], expected[0], rtol=1e-10)
    np.testing.assert_allclose(rss[0, 0], expected[1][0], rtol=1e-10)


@needs_compiler
@pytest.mark.parametrize("bounded", [False, True])
def test_the_compiled_sweep_equals_the_numpy_sweep(bounded):
    """The Pitot model (three channels, eight linear parameters), 300 random candidates: the same
    candidates are fits, and xi1 and R agree to 1e-9 relative; with boxes on the linear parameters
    the best feasible xi1 agrees too."""
    module = casest.load_model_file("models/pitot5hole.py")
    model = module.model()
    data = module.simulate(2).subset(slice(0, 600))
    part = casest.separate(model)
    cands, _, _ = draw_candidates(model, part, casest.SweepSettings(design="random", n_candidates=300, seed=4))
    evaluator = GramEvaluator(part, data, len(cands), jit=True)
    assert evaluator._solver is not None
    lb, ub = linear_parameter_bounds(model, part)
    if bounded:  # a box that excludes some unconstrained solutions
        x_free, _, _ = evaluator.solve(cands)
        lb, ub = np.percentile(x_free, 20, axis=0), np.percentile(x_free, 80, axis=0)
    compiled = evaluator.solve(cands, lb, ub)
    solver, evaluator._solver = evaluator._solver, None
    reference = evaluator.solve(cands, lb, ub)
    evaluator._solver = solver
    np.testing.assert_array_equal(compiled[2], reference[2])
    ok = reference[2]
    assert ok.sum() > 200
    np.testing.assert_allclose(compiled[1][ok], reference[1][ok], rtol=1e-9)
    np.testing.assert_allclose(compiled[0][ok], reference[0][ok], rtol=1e-9, atol=1e-12)
    if bounded:
        assert np.all((compiled[0][ok] >= lb - 1e-12) & (compiled[0][ok] <= ub + 1e-12))


@needs_compiler
def test_ill_conditioned_candidates_go_back_to_numpy_and_to_qr():
    """A badly scaled polynomial basis (columns 1, t, t^2 on t in [1000, 1001]) with a noiseless sine:
    every candidate is beyond the screen or loses accuracy, and the sweep still equals the NumPy path's
    (which re-solves them from A)."""
    import casadi as ca

    a, b, c, k, t = (ca.SX.sym(n) for n in ("a", "b", "c", "k", "t"))
    params = [casest.Parameter(n, -10.0, 10.0, 0.5) for n in "abck"]
    model = casest.Model(params, ["t"], {"z": a + b * t + c * t**2 + ca.sin(k * t)})
    tt = np.linspace(1000.0, 1001.0, 400)
    z = 1.0 + 2.0 * tt + 3.0 * tt**2 + np.sin(0.7 * tt)
    data = casest.Dataset.from_arrays(model, tt[:, None], z[:, None])
    part = casest.separate(model)
    cands = np.array([[0.7], [0.2], [1.5], [3.0]])
    evaluator = GramEvaluator(part, data, len(cands), jit=True)
    assert evaluator._solver is not None
    compiled = evaluator.solve(cands)
    assert evaluator.n_fallback >= 1
    evaluator._solver = None
    reference = evaluator.solve(cands)
    np.testing.assert_array_equal(compiled[2], reference[2])
    np.testing.assert_allclose(compiled[1][reference[2]], reference[1][reference[2]], rtol=1e-8, atol=1e-20)
