"""Brute-force references of the global maximum-likelihood optimum, for the suites that check
that casest reaches it (``scripts/campaigns/robustness.py``, ``scripts/campaigns/optimum_net.py``).

The reference of a problem is the lowest concentrated ML cost
``J* = N/2 sum_j ln(RSS_j / N) + N m / 2`` (paper Eq. 6 with R at its optimum) found by
``scipy.optimize.least_squares`` (trf, exact CasADi Jacobian, the same box) from many starts
drawn from the parameters' priors, reweighted per channel to convergence on multi-channel
problems.
"""

from __future__ import annotations

import numpy as np

__all__ = ["concentrated_cost", "brute_force", "at_global_optimum"]


def concentrated_cost(model, data, theta) -> float:
    """min over R of paper Eq. 6 at theta: ``N/2 sum_j ln(RSS_j / N) + N m / 2``.

    Parameters
    ----------
    model : Model
    data : Dataset
    theta : array_like, shape (n_parameters,)

    Returns
    -------
    float
    """
    resid = data.outputs - model.predict(theta, data.signals)
    ms = np.mean(resid**2, axis=0)
    N, m = data.n_samples, data.outputs.shape[1]
    return float(0.5 * N * np.sum(np.log(ms)) + 0.5 * N * m)


def at_global_optimum(cost: float, reference: float) -> bool:
    """Whether ``cost`` reaches the reference optimum: within 1e-6 (log-likelihood units) or
    1e-9 relative of it, or below it.

    Parameters
    ----------
    cost, reference : float

    Returns
    -------
    bool
    """
    return bool(cost - reference <= max(1e-6, 1e-9 * abs(reference)))


def _draw(model, rng) -> np.ndarray:
    theta0 = np.empty(model.n_parameters)
    for i, p in enumerate(model.parameters):
        if np.isfinite(p.lb) and np.isfinite(p.ub) or p.prior is not None:
            theta0[i] = p.sampling_prior.ppf(rng.random(1), p.lb, p.ub)[0]
        else:
            theta0[i] = p.nominal + rng.standard_normal() * max(1.0, abs(p.nominal))
    lb, ub = model.lower_bounds, model.upper_bounds
    span = np.where(np.isfinite(ub - lb), ub - lb, 1.0)
    return np.clip(theta0, lb + 1e-9 * span, ub - 1e-9 * span)


def brute_force(model, data, n_starts: int = 300, seed: int = 0) -> tuple[float, np.ndarray]:
    """Lowest concentrated ML cost over ``n_starts`` bounded trf runs (reweighted per channel).

    Parameters
    ----------
    model : Model
    data : Dataset
    n_starts : int
        Starts drawn from the parameters' priors (``seed`` fixes them).
    seed : int

    Returns
    -------
    cost : float
        The lowest :func:`concentrated_cost` reached.
    theta : ndarray, shape (n_parameters,)
    """
    from scipy.optimize import least_squares

    rng = np.random.default_rng(seed)
    N, ny = data.n_samples, model.n_outputs
    X = data.signals.T
    f = model.function.map(N)
    jac_fn = model.jacobian_function.map(N)
    z = data.outputs.T.reshape(-1)  # channel-major, as CasADi returns h
    lb, ub = model.lower_bounds, model.upper_bounds
    best_cost, best_theta = np.inf, model.nominal.copy()
    for _ in range(n_starts):
        theta = _draw(model, rng)
        weights = np.ones(ny)
        for _ in range(30 if ny > 1 else 1):
            w = np.repeat(weights, N)
            try:
                res = least_squares(
                    lambda th: (np.asarray(f(X, th)).reshape(-1) - z) * w,
                    theta,
                    jac=lambda th: np.asarray(jac_fn(X, th)[1]).reshape(ny * N, -1) * w[:, None],
                    bounds=(lb, ub), method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=2000,
                )
            except (ValueError, np.linalg.LinAlgError):
                break
            theta = res.x
            ms = np.mean((data.outputs - model.predict(theta, data.signals)) ** 2, axis=0)
            new = 1.0 / np.sqrt(np.maximum(ms, 1e-300))
            if np.allclose(new, weights, rtol=1e-10):
                break
            weights = new
        if np.all(np.isfinite(theta)):
            cost = concentrated_cost(model, data, theta)
            if cost < best_cost:
                best_cost, best_theta = cost, theta.copy()
    return best_cost, best_theta
