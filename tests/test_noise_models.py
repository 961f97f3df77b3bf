"""The noise models are classes that carry their behaviour; the stages never compare a noise label.

Truths: the log-Cholesky map is checked against NumPy's Cholesky factor; the profile R
against the residual mean square and covariance computed here with NumPy.
"""

import ast
import pathlib

import numpy as np
import pytest

import casest
from casest.problem.noise import covariance_of

scalar2 = casest.load_model_file("scalar2")
PACKAGE = pathlib.Path(casest.__file__).parent


@pytest.fixture(scope="module")
def record():
    return scalar2.model(), scalar2.simulate(0)


def test_default_noise_is_the_diagonal_model(record):
    model, data = record
    problem = casest.Problem(model, data)
    assert isinstance(problem.noise, casest.DiagonalNoise) and problem.noise.estimated and problem.noise_term.per_channel
    assert problem.noise == casest.DiagonalNoise()
    assert problem.known_R is None and problem.n_noise == 1


def test_vector_forms_round_trip():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(3, 3))
    R_full = A @ A.T + 0.1 * np.eye(3)
    noise = casest.CorrelatedNoise()
    ell = noise.to_vector(R_full)
    assert ell.size == noise.vector_size(3) == 6
    np.testing.assert_allclose(ell[:3], np.log(np.diag(np.linalg.cholesky(R_full))), rtol=1e-12)
    np.testing.assert_allclose(noise.from_vector(ell, 3), R_full, rtol=1e-12)
    np.testing.assert_allclose(covariance_of(ell, 3), R_full, rtol=1e-12)
    diagonal = casest.DiagonalNoise()
    np.testing.assert_allclose(diagonal.from_vector(diagonal.to_vector([0.5, 2.0]), 2), [0.5, 2.0], rtol=1e-15)


def test_profile_and_start_follow_the_noise_model(record):
    model, data = record
    theta = model.vector(scalar2.TRUTH)
    resid = data.outputs - model.predict(theta, data.signals)
    floor = np.array([1e-12])
    diagonal = casest.Problem(model, data)
    np.testing.assert_allclose(diagonal.noise.profile(diagonal, theta), np.mean(resid**2, axis=0), rtol=1e-12)
    known = casest.Problem(model, data, noise=casest.KnownNoise({"z": 0.25}))
    np.testing.assert_allclose(known.noise.start(known, theta, floor), [0.0625], rtol=1e-15)
    lo, hi = known.noise.stage2_bounds(floor, np.array([0.0625]))
    np.testing.assert_array_equal(lo, hi)  # held: equal bounds
    assert known.noise.decision_bounds(floor)[0].size == 0 and not known.noise.estimated
    full = casest.Problem(model, data, noise=casest.CorrelatedNoise())
    np.testing.assert_allclose(full.noise.profile(full, theta), resid.T @ resid / data.n_samples, rtol=1e-12)
    assert not full.noise_term.per_channel and full.n_noise == 1


def test_known_noise_expands_per_experiment_and_back(record):
    model, data = record
    noise = casest.KnownNoise({"z": 0.3})
    expanded = noise.for_experiments(model.output_names, ("a", "b"))
    assert dict(expanded.std) == {"z@a": 0.3, "z@b": 0.3}
    assert expanded.for_declared_outputs(model.output_names, ("a", "b")) == noise
    # two records (the same record twice is refused: it would count twice)
    problem = casest.Problem(model, {"a": data, "b": data.subset(slice(0, data.n_samples - 1))}, noise=noise)
    assert dict(problem.noise.std) == {"z@a": 0.3, "z@b": 0.3}


def test_a_noise_model_that_is_not_one_is_refused(record):
    model, data = record
    with pytest.raises(casest.OptionError, match="noise must be casest.DiagonalNoise"):
        casest.Problem(model, data, noise="known")


def _is_noise_label(node) -> bool:
    """``x.noise_kind``, ``x.noise_model`` or ``noise.kind`` / ``x.noise.kind``."""
    if not isinstance(node, ast.Attribute):
        return isinstance(node, ast.Name) and node.id == "noise_kind"
    if node.attr in ("noise_kind", "noise_model"):
        return True
    owner = node.value
    return node.attr == "kind" and (getattr(owner, "id", None) == "noise" or getattr(owner, "attr", None) == "noise")


def test_no_module_compares_a_noise_label():
    """Code decides with the noise model's attributes and methods, never with its label."""
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare) and any(_is_noise_label(n) for n in [node.left, *node.comparators]):
                offenders.append(f"{path.name}:{node.lineno}")
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "startswith":
                target = node.func.value
                if isinstance(target, ast.Attribute) and target.attr in ("noise_kind", "noise_model"):
                    offenders.append(f"{path.name}:{node.lineno}")
    assert offenders == []
