"""The SIMD sums of stage 1 (casest/backend/lane_code.py, lane_sums.py) against CasADi's own
evaluation of the same function: every operation with a vector form, the lane-by-lane build,
operations without a vector form, and the sweep's Tr[R] against the scalar map-reduce."""

import casadi as ca
import numpy as np
import pytest

import casest
from casest.backend import lane_code
from casest.backend.lane_code import lane_source
from casest.backend.lane_sums import LaneSum
from casest._casadi.c_library import load_library
from casest._casadi.numerics import compiler_available

pytestmark = pytest.mark.skipif(not compiler_available(), reason="needs a C compiler")


def _every_operation():
    x, p = ca.SX.sym("x", 2), ca.SX.sym("p", 2)
    a, b = x[0] * p[0], x[1] + p[1]  # a in (0.05, 3), b in (0.6, 3.5)
    terms = [a + b, a - b, a * b, a / b, -a, 2 * a, a ** 2, 1 / a, ca.sqrt(a), ca.fabs(a - 1), ca.sign(a - 1),
             ca.floor(3 * a), ca.ceil(3 * a), a < b, a <= b, a == b, a != b, ca.logic_not(a > 1),
             ca.logic_and(a > 1, b > 2), ca.logic_or(a > 1, b > 2), ca.if_else(a > 1, b, 0), ca.power(a, b),
             a ** 2.5, ca.atan2(a, b), ca.hypot(a, b), ca.fmin(a, b), ca.fmax(a, b), ca.fmod(b, a),
             ca.copysign(a, b - 2), ca.sin(a), ca.cos(a), ca.tan(a / 3), ca.exp(a), ca.log(a), ca.asin(a / 4),
             ca.acos(a / 4), ca.atan(a), ca.sinh(a), ca.cosh(a), ca.tanh(a), ca.asinh(a), ca.acosh(1 + a),
             ca.atanh(a / 4), ca.erf(a), ca.log1p(a), ca.expm1(a), ca.SX(2.5)]
    return ca.Function("every_op", [x, p], [ca.vertcat(*terms)])


def _reference(fun, X, P):
    """CasADi's evaluation, summed over the samples, per candidate (M, n_out)."""
    return np.array([np.asarray(fun.map(X.shape[0])(X.T, np.tile(q[:, None], (1, X.shape[0])))).sum(axis=1)
                     for q in P])


def test_every_operation_matches_casadi():
    # reference: CasADi's own evaluation of the same function (libmvec is within 4 ulp per call)
    fun = _every_operation()
    rng = np.random.default_rng(0)
    X, P = rng.uniform(0.1, 2.0, (333, 2)), rng.uniform(0.5, 1.5, (7, 2))  # 7: a group with 3 spare lanes
    lanes = LaneSum.build(fun, [X], "every_op_sum")
    assert lanes is not None
    got, ref = lanes(P), _reference(fun, X, P)
    assert got.shape == ref.shape == (7, fun.nnz_out(0))
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


def test_lane_by_lane_build_matches():
    # the build without libmvec (CASEST_LANEWISE): the same function, libm per lane
    fun = _every_operation()
    source = lane_source(fun, 1, "every_op_lw")
    flags = ("-O3", "-march=native", "-shared", "-fPIC", "-fno-math-errno")
    lib = load_library("#define CASEST_LANEWISE\n" + source, flags, (("-lm",),), prefix="lanewise_")
    import ctypes

    rng = np.random.default_rng(1)
    X, P = rng.uniform(0.1, 2.0, (50, 2)), rng.uniform(0.5, 1.5, (4, 2))
    summed = LaneSum(lib.every_op_lw, fun.nnz_out(0), 2, X, lanes=lib.every_op_lw_lanes())
    summed._function.argtypes = [ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p]
    np.testing.assert_allclose(summed(P), _reference(fun, X, P), rtol=1e-13, atol=1e-13)


def test_nan_and_inf_reach_the_sums():
    # a candidate where the model is not finite at one sample must not come out finite
    x, p = ca.SX.sym("x"), ca.SX.sym("p")
    fun = ca.Function("f", [x, p], [ca.vertcat(ca.log(x - p), 1 / (x - p))])
    X = np.array([[1.0], [2.0], [3.0]])
    out = LaneSum.build(fun, [X], "nan_sum")(np.array([[0.0], [2.0], [5.0]]))
    assert np.isfinite(out[0]).all()
    assert not np.isfinite(out[1]).any() and np.isnan(out[2, 0])


def test_operations_without_a_vector_form_keep_the_scalar_path():
    x, p = ca.SX.sym("x"), ca.SX.sym("p")
    inner = ca.Function("inner", [x], [x ** 2], {"never_inline": True})
    called = ca.Function("outer", [x, p], [inner(x) * p])
    assert lane_source(called, 1, "outer") is None
    sparse = ca.Function("sparse", [x, p], [ca.vertcat(x * p, ca.SX(1, 1))])  # a structural zero in the output
    assert not sparse.sparsity_out(0).is_dense() and lane_source(sparse, 1, "sparse") is None
    mx = ca.MX.sym("x")
    assert lane_source(ca.Function("mx", [mx, ca.MX.sym("p")], [mx]), 1, "mx") is None
    assert set(lane_code._MVEC_UNARY) & set(lane_code._UNARY) == set()


def test_sweep_gram_on_lanes_equals_a_and_b_by_hand():
    # the Pitot sweep's Gram sums from the SIMD path against [A y]'[A y] from CasADi's A and b, summed in NumPy
    from casest.two_stage.sweep.evaluators import GramEvaluator, evaluate_candidates
    from casest.two_stage.sweep import draw_candidates

    pitot = casest.load_model_file("pitot5hole")
    model = pitot.model()
    d = pitot.simulate(0)
    data = casest.Dataset.from_arrays(model, d.signals[:2000], d.outputs[:2000])
    part = casest.separate(model)
    cands, _, _ = draw_candidates(model, part, casest.SweepSettings(design="random", n_candidates=30, seed=1))
    simd = GramEvaluator(part, data, 30, jit=True, threads=2)
    assert simd._lanes is not None
    np.testing.assert_allclose(simd.gram(cands), _gram_by_hand(part, data, cands), rtol=1e-10)
    _, R, ok = evaluate_candidates(simd, data.outputs, cands)
    assert ok.all() and np.isfinite(R).all()


def test_a_sweep_below_the_compile_threshold_uses_the_compiled_sums_once_cached(tmp_path, monkeypatch):
    """N x K below SweepSettings.jit_min_work: with an empty compile cache the sweep sums in NumPy and
    compiles nothing; once a sweep of the same structure at or above the threshold has compiled
    the sums, a small sweep with the default jit=None uses them (no compile of its own), one
    with jit=False never does, and both paths give the Gram sums of A and b by hand (1e-10)."""
    from casest._casadi.memory import clear_memory_caches
    from casest.two_stage.sweep import draw_candidates
    from casest.two_stage.sweep.evaluators import GramEvaluator
    from casest.two_stage.sweep.orchestration import candidate_evaluator

    if not compiler_available():
        pytest.skip("no C compiler on this machine")
    monkeypatch.setenv("CASEST_CACHE_DIR", str(tmp_path / "cache"))
    clear_memory_caches()
    m = casest.load_model_file("scalar2")
    model, data = m.model(), m.simulate(seed=1, n=50)
    part = casest.separate(model)
    cands, _, _ = draw_candidates(model, part, casest.SweepSettings(design="random", n_candidates=20, seed=2))
    settings = casest.SweepSettings()
    assert not settings.resolved_jit(data.n_samples, len(cands))  # 1000 < 1e6
    uncached = GramEvaluator(part, data, len(cands), jit=False, cached=True)
    compiled = lambda: list((tmp_path / "cache").glob("**/lanes_*.so"))  # noqa: E731
    assert not isinstance(uncached._lanes, LaneSum) and not compiled()
    GramEvaluator(part, data, len(cands), jit=True)  # a sweep above the threshold compiles the sums
    assert compiled()
    cached = GramEvaluator(part, data, len(cands), jit=False, cached=True)
    assert isinstance(cached._lanes, LaneSum) and len(compiled()) == 1
    assert not isinstance(GramEvaluator(part, data, len(cands), jit=False)._lanes, LaneSum)  # jit=False: never
    # the sweep's default settings (jit=None) ask for it below the threshold
    assert isinstance(candidate_evaluator(model, part, data, settings, len(cands))._lanes, LaneSum)
    truth = _gram_by_hand(part, data, cands)
    np.testing.assert_allclose(uncached.gram(cands), truth, rtol=1e-10)
    np.testing.assert_allclose(cached.gram(cands), truth, rtol=1e-10)
    clear_memory_caches()


def _gram_by_hand(part, data, cands):
    """Per-channel [A y]'[A y] from A and b evaluated by CasADi (BulkEvaluator), summed in NumPy."""
    from casest.two_stage.sweep.evaluators import BulkEvaluator

    bulk = BulkEvaluator(part, data, 64.0, len(cands))
    A, b = bulk(cands)
    M, ny, n1 = len(cands), data.outputs.shape[1], part.n_linear
    y = data.outputs.reshape(-1)[None, :] - b
    Ay = np.concatenate([A, y[..., None]], axis=2).reshape(M, -1, ny, n1 + 1)
    return np.einsum("mkja,mkjb->mjab", Ay, Ay)


def test_bulk_a_and_b_from_lanes_equal_casadi():
    # A and b of the stage-1 fallback from the SIMD values against CasADi's own evaluation (jit=False)
    from casest.two_stage.sweep.evaluators import BulkEvaluator

    x, a, k, c = ca.SX.sym("x"), ca.SX.sym("a"), ca.SX.sym("k"), ca.SX.sym("c")
    params = [casest.Parameter("a", -5, 5, 1.0), casest.Parameter("c", -5, 5, 0.0), casest.Parameter("k", 0.1, 2, 1.0)]
    model = casest.Model(params, ["x"], {"z1": a * ca.exp(-k * x) + c, "z2": a * ca.sin(k * x)})
    xs = np.linspace(0, 1, 53)
    data = casest.Dataset.from_arrays(model, xs[:, None], np.column_stack([np.exp(-xs), np.sin(xs)]))
    part = casest.separate(model)
    cands = np.array([[0.5], [1.0], [1.5], [1.9], [0.2]])  # five: a group with three spare lanes
    simd = BulkEvaluator(part, data, 64.0, 5, jit=True)
    assert simd._lanes is not None
    A1, b1 = simd(cands)
    A0, b0 = BulkEvaluator(part, data, 64.0, 5, jit=False)(cands)
    assert A1.shape == A0.shape == (5, 53 * 2, 2) and b1.shape == b0.shape == (5, 53 * 2)
    np.testing.assert_allclose(A1, A0, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(b1, b0, rtol=1e-14, atol=1e-15)


def test_vector_width_follows_the_cpu_and_both_widths_agree():
    # the library reports 8 lanes where the compiler targets AVX-512 (-march=native), else 4; the
    # four-lane build of the same source (CASEST_LANES4) gives the same sums: reference CasADi, within
    # libmvec's 4 ulp per call
    import ctypes
    import subprocess

    from casest._casadi.numerics import c_compiler

    fun = _every_operation()
    rng = np.random.default_rng(2)
    X, P = rng.uniform(0.1, 2.0, (101, 2)), rng.uniform(0.5, 1.5, (11, 2))  # 11: spare lanes at both widths
    native = LaneSum.build(fun, [X], "width_native")
    macros = subprocess.run([c_compiler(), "-march=native", "-dM", "-E", "-x", "c", "/dev/null"],
                            capture_output=True, text=True).stdout
    assert native.lanes == (8 if "__AVX512F__" in macros else 4)
    source = lane_source(fun, 1, "width_four")
    flags = ("-O3", "-march=native", "-shared", "-fPIC", "-fno-math-errno")
    lib = load_library("#define CASEST_LANES4\n" + source, flags, (("-lmvec", "-lm"), ("-DCASEST_LANEWISE", "-lm")),
                       prefix="lanes4_")
    four = LaneSum(lib.width_four, fun.nnz_out(0), 2, X, lanes=lib.width_four_lanes())
    four._function.argtypes = [ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p]
    assert four.lanes == 4
    ref = _reference(fun, X, P)
    np.testing.assert_allclose(native(P), ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(four(P), ref, rtol=1e-12, atol=1e-12)
