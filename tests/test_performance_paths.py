"""The fast paths (Gram stage 1, per-sample derivative sums in stage 2) against references.

Expected values come from independent computations on the same data: column-scaled QR
on A itself (stage 1), CasADi's automatic Hessian of the whole cost and central finite
differences of the reduced cost (stage 2). Tolerances are stated per assertion.
"""

import casadi as ca
import numpy as np
import pytest

import casest
from casest.two_stage.sweep import draw_candidates
from casest.two_stage.sweep.evaluators import BulkEvaluator, GramEvaluator, evaluate_candidates
from casest.problem import data_symbols, data_vector
from casest.two_stage.solve import SolverSettings
from casest.two_stage.solve.nlps import sums_nlp
from casest.backend.sums import compiler_available, ml_sums, symmetric

needs_compiler = pytest.mark.skipif(not compiler_available(), reason="no C compiler for CasADi's JIT")


@pytest.fixture(scope="module")
def pitot_short():
    module = casest.load_model_file("models/pitot5hole.py")
    data = module.simulate(3)
    return module, module.model(), data.subset(slice(0, 3000))


@pytest.mark.parametrize("threads,jit", [(1, False), (2, False), pytest.param(2, True, marks=needs_compiler)])
def test_gram_sweep_equals_qr_sweep(pitot_short, threads, jit):
    """Gram normal equations reproduce batched QR on A to 1e-9 relative (R and xi1)."""
    _, model, data = pitot_short
    part = casest.separate(model)
    cands, _, _ = draw_candidates(model, part, casest.SweepSettings(design="random", n_candidates=40, seed=2))
    gram = GramEvaluator(part, data, len(cands), jit=jit, threads=threads)
    x_g, R_g, ok_g = gram.solve(cands)
    x_q, R_q, ok_q = evaluate_candidates(BulkEvaluator(part, data, 64.0, len(cands)), data.outputs, cands)
    assert ok_g.all() and ok_q.all()
    np.testing.assert_allclose(R_g, R_q, rtol=1e-9)
    np.testing.assert_allclose(x_g, x_q, rtol=1e-9, atol=1e-9)


def test_a_gram_pass_goes_to_threads_only_where_its_work_repays_the_handoff(pitot_short, monkeypatch):
    """Candidates are split over threads only when each part holds THREAD_MIN_WORK candidate-samples
    (a pool handoff costs 0.1-0.2 ms: smaller passes ran slower on two threads); the split changes
    no number (truth: the same candidates on one thread)."""
    from casest.two_stage.sweep import evaluators

    _, model, data = pitot_short
    part = casest.separate(model)
    cands, _, _ = draw_candidates(model, part, casest.SweepSettings(design="random", n_candidates=40, seed=5))
    work_per_candidate = data.n_samples * data.outputs.shape[1]
    submitted = []
    serial = GramEvaluator(part, data, len(cands), threads=1).solve(cands)
    threaded = GramEvaluator(part, data, len(cands), threads=2)
    real_pool = threaded._thread_pool
    monkeypatch.setattr(threaded, "_thread_pool", lambda: submitted.append(1) or real_pool())
    few = max(1, int(evaluators.THREAD_MIN_WORK // work_per_candidate) - 1)  # below the work of two parts
    threaded.solve(cands[:few])
    assert not submitted
    both = threaded.solve(cands)  # 40 candidates: above it
    assert len(cands) * work_per_candidate >= 2 * evaluators.THREAD_MIN_WORK and submitted
    for a, b in zip(both, serial):
        np.testing.assert_array_equal(a, b)


def test_gram_falls_back_to_qr_where_normal_equations_lose_accuracy():
    """Exact fit (cancellation in y'y - x'A'y) and a badly scaled polynomial go to QR."""
    a, b, c, k, t = (ca.SX.sym(n) for n in ("a", "b", "c", "k", "t"))
    params = [casest.Parameter(n, -10.0, 10.0, 0.5) for n in "abck"]
    model = casest.Model(params, ["t"], {"z": a + b * t + c * t**2 + ca.sin(k * t)})
    tt = np.linspace(1000.0, 1001.0, 400)  # columns 1, t, t^2 nearly collinear
    z = 1.0 + 2.0 * tt + 3.0 * tt**2 + np.sin(0.7 * tt)  # noiseless: exact fit at k = 0.7
    data = casest.Dataset.from_arrays(model, tt[:, None], z[:, None])
    part = casest.separate(model)
    cands = np.array([[0.7], [0.2], [1.5]])
    gram = GramEvaluator(part, data, 3)
    x_g, R_g, ok_g = gram.solve(cands)
    x_q, R_q, ok_q = evaluate_candidates(BulkEvaluator(part, data, 64.0, 3), data.outputs, cands)
    assert gram.n_fallback >= 1
    np.testing.assert_array_equal(ok_g, ok_q)
    np.testing.assert_allclose(R_g[ok_g], R_q[ok_q], rtol=1e-8, atol=1e-20)


def test_refined_normal_equations_equal_qr_on_ill_conditioned_bases():
    """Overlapping Gaussian radial basis functions (20 columns, scaled normal equations at condition
    numbers 1e10-1e15): the refined normal equations give the residual sum of squares of
    column-scaled QR to 1e-10 relative and the same xi1 to 1e-4 (relative to its largest entry,
    QR's own accuracy there being about cond(A) eps); the stage-1 sweep with the fallback equals
    QR candidate by candidate; SweepSettings(condition_limit) is checked."""
    from casest.backend.least_squares import batched_least_squares, refined_least_squares

    rng = np.random.default_rng(4)
    x = rng.uniform(0.0, 1.0, 800)
    widths = np.linspace(0.124, 0.156, 12)
    A = np.exp(-((x[None, :, None] - np.linspace(0, 1, 20)[None, None, :]) / widths[:, None, None]) ** 2)
    y = np.sin(7 * x)[None, :] + 0.01 * rng.standard_normal((12, 800))
    d = np.linalg.norm(A, axis=1)
    normal = np.einsum("mki,mkj->mij", A, A) / (d[:, :, None] * d[:, None, :])
    assert np.linalg.cond(normal).min() > 1e10 and np.linalg.cond(normal).max() < 1e16
    x_r, solved = refined_least_squares(A, y, normal, d)
    x_q, full = batched_least_squares(A, y)
    rss = lambda sol: np.sum((y - np.einsum("mkn,mn->mk", A, sol)) ** 2, axis=1)
    np.testing.assert_allclose(rss(x_r[solved]), rss(x_q)[solved], rtol=1e-10)
    assert solved.sum() >= 6 and full.all()
    scale = np.abs(x_q[solved]).max(axis=1, keepdims=True)
    assert np.max(np.abs(x_r[solved] - x_q[solved]) / scale) < 1e-4
    # the factor of [A D^-1, y] without Q (the sweep's fallback) solves the same problems: the same
    # residual sums of squares to 1e-10, the same rank decisions (a duplicated column: rank-deficient)
    x_nq, full_nq = batched_least_squares(A, y, without_q=True)
    np.testing.assert_array_equal(full_nq, full)
    np.testing.assert_allclose(rss(x_nq), rss(x_q), rtol=1e-10)
    twin = np.concatenate([A[:2], A[:2, :, :1]], axis=2)
    assert not batched_least_squares(twin, y[:2], without_q=True)[1].any()
    assert not batched_least_squares(twin, y[:2])[1].any()

    w, k = ca.SX.sym("w"), ca.SX.sym("k")
    a = [ca.SX.sym(f"a{i}") for i in range(20)]
    t = ca.SX.sym("t")
    params = [casest.Parameter(f"a{i}", -50.0, 50.0, 0.0) for i in range(20)]
    params += [casest.Parameter("w", 0.124, 0.156, 0.14), casest.Parameter("k", 5.0, 9.0, 7.0)]
    h = sum(a[i] * ca.exp(-((t - i / 19) / w) ** 2) for i in range(20)) + ca.sin(k * t)
    model = casest.Model(params, ["t"], {"z": h})
    data = casest.Dataset.from_arrays(model, x[:, None], (np.sin(7 * x) + 0.01 * rng.standard_normal(800))[:, None])
    part = casest.separate(model)
    cands = np.column_stack([np.linspace(0.124, 0.156, 9), np.linspace(5.0, 9.0, 9)])
    gram = GramEvaluator(part, data, len(cands))
    _, R_g, ok_g = gram.solve(cands)
    _, R_q, ok_q = evaluate_candidates(BulkEvaluator(part, data, 64.0, len(cands)), data.outputs, cands)
    assert gram.n_fallback >= 5
    np.testing.assert_array_equal(ok_g, ok_q)
    np.testing.assert_allclose(R_g[ok_g], R_q[ok_q], rtol=1e-10)
    with pytest.raises(casest.OptionError, match="condition_limit"):
        casest.SweepSettings(condition_limit=0.5)


@pytest.mark.parametrize("threads,jit", [(1, False), (3, False), (7, False), pytest.param(2, True, marks=needs_compiler)])
def test_sample_sums_equal_automatic_hessian(pitot_short, threads, jit):
    """Per-sample derivative sums equal CasADi's AD of the whole cost to 1e-10 relative (7 threads: N = 3000 leaves a 4-sample tail)."""
    module, model, data = pitot_short
    N = data.n_samples
    sums = ml_sums(model, N, np.ones(model.n_parameters), threads, jit)
    theta = model.vector(module.TRUTH) * 0.95
    rho = np.log(np.var(data.outputs, axis=0))
    w = np.concatenate([theta, rho])
    X, Z = data.signals.T, data.outputs.T
    p, Xs, Zs = data_symbols(model, N)
    th, r = ca.MX.sym("th", model.n_parameters), ca.MX.sym("r", model.n_outputs)
    # Eq. 6 written out independently of casest.sums: residual sums of squares S_j, then J
    S = ca.sum2((Zs - model.function.map(N)(Xs, th)) ** 2)
    J = 0.5 * ca.sum1(ca.exp(-r) * S) + 0.5 * N * ca.sum1(r)
    ref = ca.Function("ref", [th, r, p], [J, ca.gradient(J, ca.vertcat(th, r)), ca.hessian(J, ca.vertcat(th, r))[0]])
    J_ref, g_ref, H_ref = (np.asarray(v) for v in ref(theta, rho, data_vector(data)))
    H = np.asarray(ca.densify(symmetric(ca.DM(sums.hessian(w, X, Z))))) * N
    f, g = (np.asarray(v) * N for v in sums.gradient(w, X, Z))
    np.testing.assert_allclose(float(sums.cost(w, X, Z)) * N, J_ref, rtol=1e-12)
    np.testing.assert_allclose(g.ravel(), g_ref.ravel(), rtol=1e-10, atol=1e-10 * np.abs(g_ref).max())
    np.testing.assert_allclose(H, H_ref, rtol=1e-10, atol=1e-10 * np.abs(H_ref).max())


def test_reduced_mode_hessian_is_the_exact_hessian_of_the_reduced_cost(scalar2):
    """Schur-complement Hessian vs central differences of the reduced gradient (1e-5 relative)."""
    model, data = scalar2.model(), scalar2.simulate(4)
    part = casest.separate(model)
    prob = sums_nlp(model, part, data.n_samples, "reduced", SolverSettings())
    u = np.concatenate([model.vector(scalar2.TRUTH)[list(part.nonlinear_index)] / prob.scale, [np.log(0.1)]])
    with casest.Problem(model, data).data_argument() as p:
        g0, H = (np.asarray(v) for v in prob.newton(u, p))
        step = 1e-5
        H_fd = np.column_stack([
            (np.asarray(prob.newton(u + step * e, p)[0]) - np.asarray(prob.newton(u - step * e, p)[0])).ravel()
            / (2 * step) for e in np.eye(len(u))
        ])
    np.testing.assert_allclose(H, H_fd, rtol=1e-5, atol=1e-7 * np.abs(H).max())


@pytest.mark.parametrize("n_samples, threads", [(10001, 1), (10001, 2), (4096, 2), (9, 2), (70001, 1), (70001, 2)])
def test_map_sum_equals_the_plain_sum_for_any_block_split(n_samples, threads):
    # truth: the per-sample function summed in NumPy; the blocks (fixed SUM_BLOCK, padded with
    # copies of the last sample whose terms are subtracted) must not change the sum (1e-12)
    import casadi as ca

    from casest.backend.sums import Record, bound_sum, map_sum

    x, z, w = ca.SX.sym("x", 2), ca.SX.sym("z"), ca.SX.sym("w", 2)
    f = ca.Function("f", [x, z, w], [(z - w[0] * ca.sin(x[0]) - w[1] * x[1]) ** 2, ca.vertcat(x[0] * w[1], z)])
    rng = np.random.default_rng(n_samples)
    X, Z, W = rng.standard_normal((2, n_samples)), rng.standard_normal((1, n_samples)), np.array([0.7, -1.3])
    total, vec = map_sum(f, n_samples, threads)(X, Z, W)
    expect = np.sum((Z[0] - W[0] * np.sin(X[0]) - W[1] * X[1]) ** 2)
    np.testing.assert_allclose(float(total), expect, rtol=1e-12)
    # the same sums with the data outside the graph (bound to a Record, read in place)
    with Record(X.T, Z.T) as record:
        bound_total, bound_vec = bound_sum(f, n_samples, threads)(record.handle, W)
    np.testing.assert_allclose(float(bound_total), expect, rtol=1e-12)
    # signed terms: the block order changes the rounding, bounded by eps x the sum of |terms|
    scale = np.array([np.abs(X[0]).sum() * abs(W[1]), np.abs(Z).sum()])
    np.testing.assert_allclose(np.asarray(bound_vec).ravel(), [np.sum(X[0]) * W[1], np.sum(Z)], rtol=0, atol=1e-13 * scale.max())
    with pytest.raises(RuntimeError, match="no record is bound"):  # CasADi re-raises the callback's error
        bound_sum(f, n_samples, threads)(record.handle, W)
    np.testing.assert_allclose(np.asarray(vec).ravel(), [np.sum(X[0]) * W[1], np.sum(Z)], rtol=1e-11, atol=1e-9)


def test_stage2_on_a_long_record_keeps_the_data_outside_its_graph(scalar2):
    # from BOUND_MIN_SAMPLES samples the NLP's parameter is one record handle, so its build
    # does not grow with N; its solution equals the in-graph one (solved on the same data
    # with the threshold raised) to IPOPT's tolerance
    from casest.backend import sums

    model = scalar2.model()
    part = casest.separate(model)
    N = sums.BOUND_MIN_SAMPLES + 7
    data = scalar2.simulate(1, n=N)
    settings = SolverSettings(jit=False)
    for mode in ("full", "reduced"):
        assert sums_nlp(model, part, N, mode, settings)._nlp["p"].numel() == 1
        assert sums_nlp(model, part, 500, mode, settings)._nlp["p"].numel() == 500 * 2
    start = model.vector(scalar2.TRUTH) * 1.1
    outside = casest.solve_stage2(model, data, start, part, "full", settings)
    limit = sums.BOUND_MIN_SAMPLES
    try:
        sums.BOUND_MIN_SAMPLES = 10**9
        casest._casadi.memory.clear_memory_caches()
        inside = casest.solve_stage2(model, data, start, part, "full", settings)
    finally:
        sums.BOUND_MIN_SAMPLES = limit
        casest._casadi.memory.clear_memory_caches()
    assert outside.success and inside.success
    np.testing.assert_allclose(outside.theta, inside.theta, rtol=1e-7, atol=1e-9)
    assert outside.cost == pytest.approx(inside.cost, rel=1e-12)


def test_bound_sums_evaluate_concurrently_from_threads():
    # one bound sum, four records, four threads at once: each thread gets its own buffers and
    # its record's exact sum (truth: NumPy)
    from concurrent.futures import ThreadPoolExecutor

    import casadi as ca

    from casest.backend.sums import Record, bound_sum

    x, z, w = ca.SX.sym("x"), ca.SX.sym("z"), ca.SX.sym("w")
    f = ca.Function("f", [x, z, w], [(z - w * x) ** 2])
    summed = bound_sum(f, 5000, 1)
    rng = np.random.default_rng(5)
    records = [(rng.standard_normal((5000, 1)), rng.standard_normal((5000, 1))) for _ in range(4)]

    def run(k):
        X, Z = records[k]
        with Record(X, Z) as record:
            return [float(summed(record.handle, 0.3 * k)) for _ in range(50)]

    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(run, range(4)))
    for k, values in enumerate(results):
        X, Z = records[k]
        np.testing.assert_allclose(values, np.sum((Z - 0.3 * k * X) ** 2), rtol=1e-12)


def test_a_bound_sum_asked_again_at_the_same_point_and_record_is_not_summed_again(monkeypatch):
    # IPOPT asks the cost, gradient and Hessian at one point, each built on the same sums; the
    # second ask returns the first's values (truth: NumPy), another point or record sums anew
    import casadi as ca

    from casest.backend import sums

    x, z, w = ca.SX.sym("x"), ca.SX.sym("z"), ca.SX.sym("w")
    summed = sums.bound_sum(ca.Function("f", [x, z, w], [(z - w * x) ** 2]), 5000, 1)
    passes = []
    original = sums._BoundSum._sums
    monkeypatch.setattr(sums._BoundSum, "_sums", lambda self, *a: passes.append(1) or original(self, *a))
    rng = np.random.default_rng(8)
    X, Z = rng.standard_normal((5000, 1)), rng.standard_normal((5000, 1))
    with sums.Record(X, Z) as record:
        first, again = float(summed(record.handle, 0.4)), float(summed(record.handle, 0.4))
        assert len(passes) == 1 and first == again == pytest.approx(np.sum((Z - 0.4 * X) ** 2), rel=1e-12)
        assert float(summed(record.handle, 0.5)) == pytest.approx(np.sum((Z - 0.5 * X) ** 2), rel=1e-12)
        assert len(passes) == 2
    with sums.Record(X, 2 * Z) as other:
        assert float(summed(other.handle, 0.5)) == pytest.approx(np.sum((2 * Z - 0.5 * X) ** 2), rel=1e-12)
    assert len(passes) == 3


def test_nist_breakdown_script_splits_the_warm_pipeline(tmp_path):
    """scripts/benchmarks/nist_breakdown.py on Misra1a from start 1 (one repeat): the stages' times fit inside the
    wall time of the call, the ratio is that wall time over SciPy's, stage 2 is compared with SciPy
    from the same starts, the verdict is one of the sweep's, the starts appear with their outcome, and
    the table is written to --out."""
    import os
    import subprocess
    import sys

    from casest.two_stage.sweep.settings import VERDICTS

    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = tmp_path / "breakdown.md"
    proc = subprocess.run([sys.executable, os.path.join(repo, "scripts", "benchmarks", "nist_breakdown.py"), "--problems", "Misra1a/1",
                           "--repeats", "1", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    row = next(line for line in out.read_text().splitlines() if line.startswith("| Misra1a/1 |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    pipeline, stage1, stage2, rest, scipy, ratio = (float(c) for c in cells[1:7])
    assert min(stage1, stage2, rest, scipy) >= 0 and pipeline > 0  # the stages fit inside the call's wall time
    assert ratio == pytest.approx(pipeline / scipy, rel=0.05, abs=0.01)  # from unrounded times
    scipy_starts, scipy_capped, stage2_ratio = (float(c) for c in cells[8:11])
    assert scipy_starts > 0 and scipy_capped > 0
    assert stage2_ratio == pytest.approx(stage2 / scipy_capped, rel=0.05, abs=0.01)
    assert cells[11] in VERDICTS
    assert len(cells[12].split()) >= 1 and all(":" in s for s in cells[12].split())
    assert "Within 3x of SciPy:" in out.read_text()


@pytest.mark.parametrize("n", [1, 2, 3, 5, 7])
@pytest.mark.parametrize("limit", [1e4, 1e10, 1e16])
def test_condition_screen_equals_the_eigenvalue_test(n, limit):
    """Truth: numpy.linalg.eigvalsh's test lambda_min * limit > lambda_max on every matrix of a stack of
    column-scaled normal matrices with conditions from 1 to beyond 1e18 (one column made nearly
    collinear with another, fixed seed) and a singular one (a zero column: the factor breaks down):
    the Cholesky screen gives the same answer on each."""
    from casest.backend.least_squares import condition_below

    rng = np.random.default_rng(7)
    A = rng.standard_normal((3000, 40, n))
    if n > 1:
        A[:, :, -1] = A[:, :, 0] + 10.0 ** rng.uniform(-10, 0, 3000)[:, None] * A[:, :, -1]
    A[0, :, -1] = 0.0
    P = np.einsum("mki,mkj->mij", A, A)
    d = np.sqrt(np.diagonal(P, axis1=1, axis2=2))
    P = P / (np.where(d > 0, d, 1.0)[:, :, None] * np.where(d > 0, d, 1.0)[:, None, :])
    eig = np.linalg.eigvalsh(P)
    expected = eig[:, 0] * limit > eig[:, -1]
    assert 0 < expected.sum() < len(expected) or n == 1 or limit == 1e16
    np.testing.assert_array_equal(condition_below(P, limit), expected)
