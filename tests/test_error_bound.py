"""The paper's cost error E and bracket (Eq. 7-13) and Eq. 17-18 as printed, against a hand
computation in NumPy on scalar examples 1 and 2 (A and b written out from Eq. 21 and 33:
z = (1 + a) cos(phase) + d, so A_k = [cos(phase_k), 1] and b_k = cos(phase_k))."""

import sys
from pathlib import Path

import numpy as np
import pytest

import casest
from casest.two_stage.sweep import SweepSettings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "models"))
import scalar1  # noqa: E402
import scalar2  # noqa: E402


def _phase(example, eta, xi2):
    """The argument of the cosine: eta + b (example 1), eta (1 + b) + c (example 2)."""
    if example is scalar1:
        return eta[None, :] + xi2[:, :1]
    return eta[None, :] * (1 + xi2[:, :1]) + xi2[:, 1:2]


def _hand_bound(example, data, landscape):
    """E (Eq. 9 with Cauchy-Schwarz over ||xi1|| <= eps1), the Eq. 13 bound and Eq. 17-18, by hand."""
    eta, best = data.signals[:, 0], landscape.best_index
    cands, Rp = landscape.candidates, landscape.best_R[0]
    cos = np.cos(_phase(example, eta, cands))  # (M, N): the nonzero column of A, and b
    d_cos = np.abs(cos - cos[best]) / np.sqrt(Rp)  # ||A_k - A_kp|| = |b_k - b_kp| here
    finite = np.all(np.isfinite(landscape.xi1), axis=1)
    eps1 = np.max(np.linalg.norm(landscape.xi1[finite], axis=1))
    E = 0.5 * np.max(np.sum((eps1 * d_cos + d_cos) ** 2, axis=1))
    distance = np.linalg.norm(cands - cands[best], axis=1)
    away = distance > 0
    L = np.max(d_cos[away].max(axis=1) / distance[away])
    N = len(eta)
    E_lip = 0.5 * N * (L * eps1 * distance.max() + L * distance.max()) ** 2
    stage1_cost = 0.5 * N * (1 + np.log(Rp))
    return E, E_lip, stage1_cost


def _hand_eq17_18(example, data, landscape, step):
    """Analytic derivatives of cos(phase) in xi2 at the best candidate."""
    eta = data.signals[:, 0]
    xi2p, xi1p = landscape.best_xi2, landscape.best_xi1
    s = -np.sin(_phase(example, eta, xi2p[None, :])[0])
    d_phase = [np.ones_like(eta)] if example is scalar1 else [eta, np.ones_like(eta)]
    db = np.array([s * dp for dp in d_phase])  # (n2, N)
    A_p = np.column_stack([np.cos(_phase(example, eta, xi2p[None, :])[0]), np.ones_like(eta)])
    ratio_A = np.linalg.norm(step @ db) / np.linalg.norm(A_p)  # only A's first column moves
    ratio_b = np.linalg.norm(step @ db) / np.linalg.norm(A_p[:, 0])

    def min_eig(cols):
        G = cols @ cols.T
        d = np.sqrt(np.diag(G))
        return np.linalg.eigvalsh(G / np.outer(d, d))[0]

    return ratio_A, ratio_b, min_eig(xi1p[0] * db), min_eig(db)


@pytest.mark.parametrize("example", [scalar1, scalar2])
def test_error_bound_equals_hand_computation(example):
    data = example.simulate(seed=0)
    est = casest.estimate(example.model(), data)
    bound, landscape = est.landscape.error_bound, est.landscape
    E, E_lip, stage1_cost = _hand_bound(example, data, landscape)
    assert bound.stage1_cost == pytest.approx(stage1_cost, rel=1e-12)
    assert bound.E == pytest.approx(E, rel=1e-10)
    assert bound.E_lipschitz == pytest.approx(E_lip, rel=1e-10)
    assert bound.E <= bound.E_eps <= bound.E_lipschitz
    # Eq. 7: the stage-2 optimum lies inside [J(xi1p, xi2p) - E, J(xi1p, xi2p)]
    assert bound.lower <= est.cost <= bound.stage1_cost
    assert bound.side(est.cost) == "inside"
    assert "as Eq. 7 states" in est.report()


@pytest.mark.parametrize("example", [scalar1, scalar2])
def test_paper_eq17_eq18_equal_analytic_derivatives(example):
    """Eq. 17's ratios with the sweep's half step, from the grid spacing of each axis."""
    data = example.simulate(seed=0)
    landscape = casest.sweep(example.model(), data)
    grid = [np.unique(landscape.candidates[: landscape.n_design, j]) for j in range(landscape.candidates.shape[1])]
    step = np.array([0.5 * np.diff(g).min() for g in grid])
    bound = landscape.error_bound
    ratio_A, ratio_b, eig_A, eig_b = _hand_eq17_18(example, data, landscape, step)
    assert bound.eq17_A == pytest.approx(ratio_A, rel=1e-5)  # central differences, relative step 1e-6
    assert bound.eq17_b == pytest.approx(ratio_b, rel=1e-5)
    if example is scalar1:  # one xi2: a 1 x 1 matrix, normalised to 1
        assert bound.eq18_A == pytest.approx(1.0) and bound.eq18_b == pytest.approx(1.0)
    else:
        assert bound.eq18_A == pytest.approx(eig_A, rel=1e-5)
        assert bound.eq18_b == pytest.approx(eig_b, rel=1e-5)


def test_bracket_sides_and_settings():
    data = scalar2.simulate(seed=1)
    landscape = casest.sweep(scalar2.model(), data, settings=SweepSettings(error_bound=False))
    assert landscape.error_bound is None
    landscape = casest.sweep(scalar2.model(), data)
    bound = landscape.error_bound
    assert bound.side(bound.stage1_cost + 1.0) == "above"
    assert bound.side(bound.lower - 1.0) == "below"
    again = type(landscape).from_dict(landscape.to_dict())
    assert again.error_bound == bound
    with pytest.raises(casest.OptionError):
        SweepSettings(error_bound="sometimes")


def test_the_bracket_is_not_compared_across_other_stage1_data_or_noise_models():
    """Eq. 7 brackets one cost: stage 1 on other data of the same length, or a known R, is not comparable."""
    data, other = scalar2.simulate(seed=0), scalar2.simulate(seed=5)
    est = casest.estimate(scalar2.model(), data, stage1_data=other)
    assert not est.landscape.error_bound.comparable and "not compared with the bracket" in est.report()
    est = casest.estimate(scalar2.model(), data, noise=casest.KnownNoise({"z": 0.3}))
    assert not est.landscape.error_bound.comparable
    est = casest.estimate(scalar2.model(), data)
    assert est.landscape.error_bound.comparable and "as Eq. 7 states" in est.report()


def test_the_bound_does_not_depend_on_the_evaluators_chunk():
    """E and Eq. 17-18 from an evaluator of one candidate per call equal those of 64 per call (the
    probes of Eq. 17-18 then take several calls, each returning its own arrays)."""
    import importlib

    evaluators = importlib.import_module("casest.two_stage.sweep.evaluators")
    error_bound = importlib.import_module("casest.two_stage.sweep.error_bound")
    model, data = scalar2.model(), scalar2.simulate(seed=0)
    land = casest.sweep(model, data)
    step = np.array([0.005, 0.01])
    bounds = [error_bound.paper_error_bound(evaluators.BulkEvaluator(casest.separate(model), data, 64.0, chunk), data,
                                            land.candidates, land.xi1, land.R, land.best_index, step)
              for chunk in (1, 64)]
    assert bounds[0].eq17_A > 0 and bounds[0].eq18_A > 0
    assert bounds[0] == bounds[1]


def test_the_difference_program_equals_the_bound_from_a_and_b(monkeypatch):
    """Uncompiled, the per-sample differences of Eq. 9-13 run as one NumPy program; on the
    magnetometer (three channels, R unequal, two samples of one channel missing) every term equals
    the one computed from the evaluator's A and b arrays (to 1e-12)."""
    import importlib

    import magnetometer  # noqa: E402

    evaluators = importlib.import_module("casest.two_stage.sweep.evaluators")
    error_bound = importlib.import_module("casest.two_stage.sweep.error_bound")
    model, data = magnetometer.model(), magnetometer.simulate(0)
    outputs = data.outputs.copy()
    outputs[[3, 7], 1] = np.nan
    data = casest.Dataset.from_arrays(model, data.signals, outputs, missing="allow")
    land = casest.sweep(model, data, settings=SweepSettings(n_candidates=300))
    bulk = evaluators.BulkEvaluator(casest.separate(model), data, 64.0, 300, jit=False)
    assert bulk.uncompiled_arrays
    step = np.full(len(land.nonlinear), 1e-3)

    def bound():
        return error_bound.paper_error_bound(bulk, data, land.candidates, land.xi1, land.R, land.best_index, step)

    program = bound()
    monkeypatch.setattr(evaluators.BulkEvaluator, "uncompiled_arrays", property(lambda self: False))
    arrays = bound()
    for name in ("E", "E_eps", "E_lipschitz", "eps_A", "eps_b", "L_A", "L_b", "eps2"):
        np.testing.assert_allclose(getattr(program, name), getattr(arrays, name), rtol=1e-12, err_msg=name)
    assert program.E > 0 and program.L_A > 0


def test_the_bound_is_computed_when_first_read_and_equals_the_direct_computation(monkeypatch):
    """The sweep leaves E to its first reader; what that reader gets (also through a pickle or a
    copy) is paper_error_bound of the sweep's own candidates, computed once."""
    import copy
    import importlib
    import pickle

    bounds = importlib.import_module("casest.two_stage.sweep.orchestration")
    calls = []
    direct = bounds.paper_error_bound
    monkeypatch.setattr(bounds, "paper_error_bound", lambda *a, **k: calls.append(1) or direct(*a, **k))
    data = scalar2.simulate(seed=0)
    landscape = casest.sweep(scalar2.model(), data)
    assert calls == []
    twin = copy.deepcopy(landscape)  # copying computes it (the evaluator stays behind), in the original too
    assert len(calls) == 1
    bound = landscape.error_bound
    assert landscape.error_bound is bound and len(calls) == 1
    assert twin.error_bound == bound
    assert pickle.loads(pickle.dumps(landscape)).error_bound == bound
    E, _, stage1_cost = _hand_bound(scalar2, data, landscape)
    assert bound.E == pytest.approx(E, rel=1e-10) and bound.stage1_cost == pytest.approx(stage1_cost, rel=1e-12)


def test_a_vacuous_bracket_and_inapplicable_eq18_are_said_so():
    """The bracket was printed as holding when E dwarfed the cost, and Eq. 18 of b was printed as 0
    beside "checks hold" for a model with b = 0. Truth: scalar2 (paper Eq. 33) has E far above
    |J(xi1p, xi2p)|; z = a cos(b eta + c) has b = 0 (no term free of xi1)."""
    import casadi as ca

    est = casest.estimate(scalar2.model(), scalar2.simulate(seed=0))
    bound = est.landscape.error_bound
    assert bound.E > abs(bound.stage1_cost) and bound.vacuous
    assert "but the bracket is vacuous" in est.report()
    a, b, c, eta = (ca.SX.sym(n) for n in ("a", "b", "c", "eta"))
    model = casest.Model([casest.Parameter("a", -2, 2), casest.Parameter("b", 0.5, 1.5), casest.Parameter("c", 0, 1)],
                         [casest.Signal("eta")], {"z": a * ca.cos(b * eta + c)})
    x = np.linspace(0, 6, 150)
    z = 1.2 * np.cos(1.1 * x + 0.3) + 0.01 * np.random.default_rng(1).standard_normal(x.size)
    zero_b = casest.estimate(model, casest.Dataset(model, {"eta": x, "z": z}))
    assert np.isnan(zero_b.landscape.error_bound.eq18_b)
    report = zero_b.report()
    assert "not applicable (b does not depend on xi2) (b)" in report
    assert "casest's linearisation and curvature checks (its forms of the paper's Eq. 17 and 18) hold" in report
