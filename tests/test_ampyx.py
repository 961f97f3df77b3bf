"""The Ampyx AP2 worked example on its real flight record (bundled, Apache 2.0).

Air-data calibration: casest's two-stage estimate reaches the optimum that an independent
SciPy multi-start fit of the same model finds (the concentrated ML cost, R diagonal and
unknown, written in NumPy without CasADi and minimised by L-BFGS-B from 16 Sobol starts in
the same box); the ML cost within 1e-8 relative."""

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.stats import qmc

import casest

air_data = casest.load_model_file("ampyx_air_data")


def _velocity(theta, X):
    """V_NED of the air-data model (models/ampyx_air_data.py), written again in NumPy."""
    lam_v, b_v, lam_a, b_a, lam_b, b_b, eps, wn, we, wd = theta
    va = (1 + lam_v) * X[:, 0] + b_v
    alpha = (1 + lam_a) * X[:, 1] + b_a
    beta = (1 + lam_b) * X[:, 2] + b_b
    d = np.stack([np.cos(alpha) * np.cos(beta), np.sin(beta), np.sin(alpha) * np.cos(beta)], axis=1)
    ce, se = np.cos(eps), np.sin(eps)
    d = np.stack([d[:, 0], ce * d[:, 1] - se * d[:, 2], se * d[:, 1] + ce * d[:, 2]], axis=1)
    C = X[:, 3:12].reshape(-1, 3, 3)
    return np.einsum("kij,kj->ki", C, d) * va[:, None] + np.array([wn, we, wd])


def _ml_cost(theta, X, Z):
    """J = N/2 sum_j ln(RSS_j / N) + N n_z / 2: paper Eq. 6 with R profiled out (R_j = RSS_j / N)."""
    r = Z - _velocity(theta, X)
    n = Z.shape[0]
    return 0.5 * n * np.sum(np.log(np.sum(r**2, axis=0) / n)) + 0.5 * n * Z.shape[1]


@pytest.mark.slow
def test_air_data_estimate_equals_a_scipy_multistart_optimum():
    model, data = air_data.model(), air_data.load()
    est = casest.estimate(model, data, sweep_settings=air_data.SWEEP_SETTINGS)
    assert est.success
    X, Z = data.signals, data.outputs
    lb, ub = model.lower_bounds, model.upper_bounds
    starts = qmc.scale(qmc.Sobol(len(lb), seed=1).random(16), lb, ub)
    fits = [minimize(_ml_cost, x0, args=(X, Z), method="L-BFGS-B", bounds=list(zip(lb, ub)),
                     options={"maxiter": 2000, "ftol": 1e-15, "gtol": 1e-10}) for x0 in starts]
    best = min(fits, key=lambda f: f.fun)
    assert abs(est.cost - best.fun) <= 1e-8 * abs(best.fun), (est.cost, best.fun)
    assert abs(est.cost - _ml_cost(est.theta, X, Z)) <= 1e-9 * abs(est.cost)  # the same criterion
    assert np.all(np.abs(est.theta - best.x) <= 0.05 * est.std + 1e-9 * np.abs(best.x)), (est.theta, best.x)


@pytest.mark.slow
def test_the_worked_example_prints_its_three_parts(capsys):
    """scripts/examples/ampyx_example.py on the bundled record: the three parts, each estimated on two
    segments and validated on the third, with the std choice and the validation metrics."""
    import importlib.util
    import os

    path = os.path.join(os.path.dirname(__file__), "..", "scripts", "examples", "ampyx_example.py")
    spec = importlib.util.spec_from_file_location("ampyx_example", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    assert example.main(["--no-figures"]) == 0
    out = capsys.readouterr().out
    for heading in ("1. Air-data calibration", "2. Flight-path reconstruction", "3. Rate responses"):
        assert heading in out
    assert out.count("[[Validation on s3 (held out)]]") == 3
    assert out.count("std reported: colored") == 3  # the residuals of every part are correlated in time
    theil = [float(line.split("Theil U = ")[1].split(",")[0]) for line in out.splitlines() if "Theil U = " in line]
    assert len(theil) == 3 + 6 + 3 and all(0.0 <= u <= 1.0 for u in theil)
