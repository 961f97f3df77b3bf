"""What a model lacks: the cheapest structural change that explains residuals that depend on something.

When the residual tests say the residuals depend on a signal, the fitted value or time
(:mod:`casest.estimation.verdict`), the candidates below are fitted to the residuals by least
squares, each as the first-order effect of one more parameter (residuals weighted by each
output's rms, so that outputs of other units count alike):

- **bias** of an output (regressor 1) and **scale** of an output (regressor: its fitted value);
- **lag** of a signal ``x`` (or of every signal together: a sensor behind its reference) behind
  or ahead of the outputs by ``m`` whole samples (each ``m`` of the cross-correlation test's
  lags): the regressor is the model's own change ``h(x(t - m)) - h(x(t))``, one coefficient
  shared by every output. For the lag that counts,
  the fraction ``f`` of a sample beyond ``m`` follows from ``h(x(t - m - f)) ~ h(x(t - m)) - f
  dh/dx x'(t - m)`` (the model's derivative in CasADi, ``x'`` the central difference), so the
  diagnosed lag ``d = m + f`` comes with a std;
- **step** of an output's level at the sample the cumulative-sum test found;
- **term** missing from an output: each signal, its square and the product of two signals.

Each candidate is fitted together with the model's own parameters (the residuals regressed on the
candidate's regressor beside the Jacobian of the model at the estimate: one Gauss-Newton step of
the changed model), so that it is judged by what it explains beyond them. A candidate counts when
its F-test is significant at the family level :data:`ALPHA` divided by the number of candidates
(Bonferroni) **and** the residuals less that step's fit pass every dependence test again. Of those that count, the cheapest kind (in the order above) with the largest F is
the diagnosis; when none counts there is no diagnosis: nothing is invented to fill the field.
``casest.refit(estimate, model, data)`` estimates the model with the change (:mod:`casest.estimation.refit`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from ..status import DiagnosisCode, ResidualCode
from .diagnostics import ALPHA, family_adjusted

__all__ = ["Diagnosis", "diagnose", "diagnose_arrays", "MAX_PRODUCT_SIGNALS"]

#: products of two signals are candidates up to this many signals (their number grows as n^2 / 2)
MAX_PRODUCT_SIGNALS = 20
#: the significant candidates, cheapest and strongest first, whose residuals are tested again
VERIFIED_CANDIDATES = 8
_COST = {DiagnosisCode.BIAS: 0, DiagnosisCode.SCALE: 0, DiagnosisCode.LAG: 1, DiagnosisCode.STEP: 2,
         DiagnosisCode.TERM: 3}


@dataclass(frozen=True)
class Diagnosis:
    """The structural change that explains the residuals (module docstring).

    Attributes
    ----------
    code : DiagnosisCode
    channels : tuple of str
        The outputs the change acts on.
    signals : tuple of str
        The signals shifted together (lag), else empty.
    term : str
        The missing term (``"x"``, ``"x^2"``, ``"x*y"``), ``"1"`` (bias), ``"fitted"`` (scale),
        ``"step"``; ``"shift"`` for a lag.
    value : float
        The change's size from the residuals: the lag ``d`` (samples; positive: the outputs follow
        the signal), or the coefficient of the term in the output's unit.
    std : float
        Its standard deviation from the same least squares.
    location : int
        A step's first sample (-1 otherwise).
    statistic, p_value : float
        The candidate's F-test on the residuals.
    rms_before, rms_after : ndarray, shape (n_channels,)
        Each channel's residual rms before and after the change's fit.
    verdict_after : ResidualCode
        What the residual tests say of the residuals less the change's fit.
    """

    code: DiagnosisCode
    channels: tuple
    signals: tuple
    term: str
    value: float
    std: float
    location: int
    statistic: float
    p_value: float
    rms_before: np.ndarray = field(repr=False)
    rms_after: np.ndarray = field(repr=False)
    verdict_after: ResidualCode

    def describe(self) -> str:
        """One sentence: what the change is, its size with std, and the misfit it removes.

        Returns
        -------
        str
        """
        fall = ", ".join(f"{c} {b:.4g} -> {a:.4g}" for c, b, a in zip(self.channels, self.rms_before, self.rms_after))
        size = f"{self.value:.4g} +/- {self.std:.2g}"
        shifted = "signal " + self.signals[0] if len(self.signals) == 1 else "signals " + ", ".join(self.signals)
        what = {DiagnosisCode.LAG: f"the outputs follow {shifted} by {size} samples (a time shift)",
                DiagnosisCode.BIAS: f"a bias of {size} is missing from {', '.join(self.channels)}",
                DiagnosisCode.SCALE: f"a scale error of {size} (relative) in {', '.join(self.channels)}",
                DiagnosisCode.STEP: f"the level of {', '.join(self.channels)} changes by {size} at sample "
                                    f"{self.location}",
                DiagnosisCode.TERM: f"the term {self.term} is missing from {', '.join(self.channels)} "
                                    f"(coefficient {size})"}[self.code]
        return (f"diagnosis: {what}; with it the residual rms falls ({fall}) and the residual tests say "
                f"{self.verdict_after.value}")

    def to_dict(self) -> dict:
        """Plain-Python form (:meth:`from_dict` reads it).

        Returns
        -------
        dict
        """
        return {"code": self.code.value, "channels": list(self.channels), "signals": list(self.signals), "term": self.term,
                "value": float(self.value), "std": float(self.std), "location": int(self.location),
                "statistic": float(self.statistic), "p_value": float(self.p_value),
                "rms_before": [float(v) for v in self.rms_before], "rms_after": [float(v) for v in self.rms_after],
                "verdict_after": self.verdict_after.value}

    @classmethod
    def from_dict(cls, data: dict) -> "Diagnosis":
        """The diagnosis of :meth:`to_dict`'s form.

        Parameters
        ----------
        data : dict

        Returns
        -------
        Diagnosis
        """
        return cls(DiagnosisCode(data["code"]), tuple(data["channels"]), tuple(data["signals"]), data["term"],
                   float(data["value"]), float(data["std"]), int(data["location"]), float(data["statistic"]),
                   float(data["p_value"]), np.asarray(data["rms_before"], dtype=float),
                   np.asarray(data["rms_after"], dtype=float), ResidualCode(data["verdict_after"]))


@dataclass(frozen=True)
class _Candidate:
    code: DiagnosisCode
    channels: tuple  # indices
    signals: tuple
    term: str
    regressor: np.ndarray  # (N, n_channels_in_candidate), unweighted
    location: int = -1


def diagnose(problem, theta: np.ndarray, checks: tuple, estimator=None) -> Diagnosis | None:
    """The diagnosis of a static model's estimate whose residuals depend on something (module docstring).

    Parameters
    ----------
    problem : Problem
        A static model's problem (dynamic models get None).
    theta : ndarray, shape (n_parameters,)
    checks : tuple of ResidualCheck
        The estimate's family of residual tests.
    estimator : callable, optional
        ``(model, data, **options) -> Estimate`` (:func:`casest.estimate`): with it, the
        candidates are verified by refitting the changed model, and the change's size and std
        come from the refit; without it, from the linear step alone.

    Returns
    -------
    Diagnosis or None
        None when the residuals do not depend on anything, or no candidate explains them.
    """
    from .verdict import residual_verdict

    if problem.measurement.simulated or _REFITTING[0] or residual_verdict(checks).code is not ResidualCode.DEPENDENT:
        return None
    model, data = problem.model, problem.data
    fitted = problem.predict(theta)
    ranked = []
    found = diagnose_arrays(data.outputs - fitted, model.output_names, data.signals, model.signal_names, fitted,
                            in_time=bool(getattr(data, "time_ordered", False)), checks=checks,
                            jacobian=problem.jacobian(theta), predict=lambda signals: model.predict(theta, signals),
                            sensitivity=lambda signals: signal_sensitivity(model, theta, signals), ranked=ranked)
    if problem.held or problem.experiments or estimator is None:
        return found
    if found is not None:  # the linear step's choice first, then the strongest of each kind
        ranked.insert(0, next(item for item in ranked if item[0].code is found.code and
                              tuple(model.output_names[j] for j in item[0].channels) == found.channels and
                              item[0].signals == found.signals and item[0].term == found.term))
    return _verified_by_refit(ranked, problem, theta, estimator) or found


#: set while a diagnosis refits a candidate, so that the refit's own estimate does not diagnose again
_REFITTING = [False]
#: candidates a diagnosis refits: the one the linear step chose, then the strongest of each other kind
REFITTED_CANDIDATES = 3


def _verified_by_refit(ranked: list, problem, theta: np.ndarray, estimator) -> Diagnosis | None:
    """The first candidate (of ``ranked``'s first and the strongest of each kind) whose nonlinear
    refit converges and leaves residuals that depend on nothing: the change's size and std from
    the refit."""
    from .refit import refit_with
    from .verdict import residual_verdict

    tried, kinds = [], set()
    for candidate, fit in ranked:
        if not tried or candidate.code not in kinds:
            tried.append((candidate, fit))
            kinds.add(candidate.code)
    model, data = problem.model, problem.data
    for candidate, (value, std, F, p, _) in tried[:REFITTED_CANDIDATES]:
        guess = Diagnosis(candidate.code, tuple(model.output_names[j] for j in candidate.channels), candidate.signals,
                          candidate.term, float(candidate.location) if candidate.code is DiagnosisCode.LAG else value,
                          std, candidate.location, F, p, np.zeros(0), np.zeros(0), ResidualCode.DEPENDENT)
        _REFITTING[0] = True
        try:
            refit = refit_with(guess, model, data, estimator, first_theta=theta)
        except Exception:  # a refit that fails is no diagnosis (the estimate stands as it is)
            continue
        finally:
            _REFITTING[0] = False
        verdict = residual_verdict(refit.estimate.residual_checks).code
        if refit.estimate.success and verdict is not ResidualCode.DEPENDENT:
            used = [model.output_names.index(c) for c in guess.channels]
            return Diagnosis(guess.code, guess.channels, guess.signals, guess.term, refit.value, refit.std,
                             guess.location if guess.code is DiagnosisCode.STEP else -1, F, p,
                             refit.rms_before[used], refit.rms_after[used], verdict)
    return None


def signal_sensitivity(model, theta, signals: np.ndarray) -> np.ndarray:
    """``dh_j/dx_i`` at every sample, shape (N, n_signals, n_outputs) (the model's exact derivative)."""
    import casadi as ca

    from .._casadi.sample_blocks import evaluate_samples

    function = ca.Function("dh_dx", [model.x, model.theta], [ca.vec(ca.jacobian(model.h, model.x))])
    (values,) = evaluate_samples(function, [signals], [np.asarray(theta, dtype=float)])
    return values.reshape(signals.shape[0], model.n_signals, model.n_outputs)


def diagnose_arrays(residuals, channels, signals, signal_names, fitted, *, in_time: bool = False,
                    jacobian: np.ndarray | None = None, predict=None, sensitivity=None,
                    ranked: list | None = None, checks: tuple | None = None) -> Diagnosis | None:
    """The diagnosis from arrays (module docstring).

    Parameters
    ----------
    residuals, fitted : ndarray, shape (N, n_channels)
    channels : sequence of str
    signals : ndarray, shape (N, n_signals)
    signal_names : sequence of str
    in_time : bool
        The record is in time order (the residual tests' labels).
    jacobian : ndarray, shape (N n_channels, n_parameters), optional
        The model's Jacobian at the estimate, sample-major (zero rows where not measured): the
        candidates are fitted beside it. Without it, beside a constant per channel.
    predict : callable, optional
        ``signals (N, n_signals) -> outputs (N, n_channels)``: the model at the estimate (the lag
        candidates need it).
    sensitivity : callable, optional
        ``signals -> dh/dx``, shape (N, n_signals, n_channels) (the lag's fraction of a sample).
    ranked : list, optional
        Filled with the significant candidates and their fits, cheapest and strongest first.
    checks : tuple of ResidualCheck, optional
        The residuals' family of tests (computed here when not given).

    Returns
    -------
    Diagnosis or None
    """
    from .residual_family import series_checks
    from .verdict import residual_verdict

    r = np.where(np.isfinite(residuals), residuals, 0.0)
    scale = np.sqrt(np.mean(r**2, axis=0))
    scale = np.where(scale > 0, scale, 1.0)
    N, ny = r.shape
    J = None if jacobian is None else np.asarray(jacobian, dtype=float).reshape(N, ny, -1)
    retest = functools.partial(series_checks, signals=signals, signal_names=signal_names, in_time=in_time,
                               dynamic=False)
    if checks is None:
        checks = retest(residuals, channels, fitted=fitted, jacobian=J)
    dependent = {c.channel for c in residual_verdict(checks).dependence}
    base = _weighted_basis(jacobian, np.isfinite(residuals), scale)
    candidates = [c for c in _candidates(r, fitted, signals, list(signal_names), predict)
                  if dependent <= {channels[j] for j in c.channels}]  # one change must explain every channel
    threshold = ALPHA / max(len(candidates), 1)
    ranked = [] if ranked is None else ranked
    for candidate in candidates:
        fit = _fitted_candidate(r / scale, base, _placed(candidate, N, ny) / scale)
        if fit is not None and fit[3] < threshold:
            ranked.append((candidate, fit))
    ranked.sort(key=lambda item: (_COST[item[0].code], -item[1][2]))
    for candidate, (value, std, F, p, correction) in ranked[:VERIFIED_CANDIDATES]:
        used = list(candidate.channels)
        corrected = r - correction * scale
        names = [channels[j] for j in used]  # its channels tested again, the others' tests as they were
        again = retest(corrected[:, used], names, fitted=(fitted + correction * scale)[:, used],
                       jacobian=None if J is None else J[:, used, :], stop_below=ALPHA / (2 * len(checks)))
        verdict = residual_verdict(family_adjusted([c for c in checks if c.channel not in names] + list(again)))
        if verdict.code is ResidualCode.DEPENDENT:
            continue
        if candidate.code is DiagnosisCode.LAG:
            value, std = _lag_with_fraction(candidate, r / scale, base, signals, list(signal_names), sensitivity,
                                            scale)
        return Diagnosis(candidate.code, tuple(channels[j] for j in used), candidate.signals, candidate.term,
                         value, std,
                         candidate.location if candidate.code is DiagnosisCode.STEP else -1, F, p,
                         np.sqrt(np.mean(r[:, used]**2, axis=0)), np.sqrt(np.mean(corrected[:, used]**2, axis=0)),
                         verdict.code)
    return None


def _shifted(signals: np.ndarray, columns: list, m: int) -> np.ndarray:
    """The signals with the given columns delayed by m samples (``x(t - m)``; the ends held)."""
    out = signals.copy()
    out[:, columns] = signals[np.clip(np.arange(signals.shape[0]) - m, 0, signals.shape[0] - 1)][:, columns]
    return out


def _lag_with_fraction(candidate, weighted: np.ndarray, base: np.ndarray, signals, names, sensitivity,
                       scale) -> tuple:
    """``(m + f, std of f)``: the whole lag m's shift and the fraction f of a sample fitted together
    beside the model's parameters (module docstring); ``(m, NaN)`` without the model's derivative."""
    m = candidate.location
    if sensitivity is None:
        return float(m), float("nan")
    columns = [names.index(n) for n in candidate.signals]
    shifted = _shifted(signals, columns, m)
    slopes = np.gradient(shifted[:, columns], axis=0)  # d h(x(t - d)) / d d = -sum_i dh/dx_i x_i'
    fraction = -np.einsum("kin,ki->kn", sensitivity(shifted)[:, columns, :], slopes) / scale
    whole = np.asarray(candidate.regressor, dtype=float) / scale
    design = np.column_stack([base, whole.reshape(-1)]) if base.size else whole.reshape(-1, 1)
    fit = _fitted_candidate(weighted, np.linalg.qr(design)[0], fraction)
    return (float(m), float("nan")) if fit is None else (m + fit[0], fit[1])


def _weighted_basis(jacobian, measured: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the model's weighted Jacobian (or of one constant per channel),
    shape (N n_channels, rank)."""
    N, ny = measured.shape
    if jacobian is None:
        design = np.kron(np.ones((N, 1)), np.eye(ny)) * measured.reshape(-1)[:, None]
    else:
        design = np.asarray(jacobian, dtype=float) * measured.reshape(-1)[:, None]
        design = design / np.tile(scale, N)[:, None]
    U, sv, _ = np.linalg.svd(design, full_matrices=False)
    keep = sv > sv[0] * 1e-10 if sv.size and sv[0] > 0 else np.zeros(sv.size, dtype=bool)
    return U[:, keep]


def _placed(candidate, N: int, ny: int) -> np.ndarray:
    """The candidate's regressor in every channel, shape (N, n_channels): zero in channels it does not act on."""
    out = np.zeros((N, ny))
    out[:, list(candidate.channels)] = np.asarray(candidate.regressor, dtype=float).reshape(N, -1)
    return out


def _candidates(r, fitted, signals, names, predict) -> list:
    """Every candidate change (module docstring), with its regressor."""
    from .independence import prewhitener, step_test

    N, ny = r.shape
    out = []
    for j in range(ny):
        out.append(_Candidate(DiagnosisCode.BIAS, (j,), (), "1", np.ones((N, 1))))
        out.append(_Candidate(DiagnosisCode.SCALE, (j,), (), "fitted", fitted[:, j:j + 1]))
        step = step_test(r[:, j], prewhitener(r[:, j]))
        if step is not None:
            indicator = (np.arange(N) >= step.location).astype(float)[:, None]
            out.append(_Candidate(DiagnosisCode.STEP, (j,), (), "step", indicator, step.location))
    if predict is not None:
        from .residual_family import cross_lags

        groups = [[i] for i in range(len(names))] + ([list(range(len(names)))] if len(names) > 1 else [])
        for columns in groups:  # each signal, and every signal together (a sensor behind its reference)
            for m in cross_lags(N, dynamic=False):
                change = predict(_shifted(signals, columns, int(m))) - fitted if m else 0.0
                if m and np.any(change):
                    out.append(_Candidate(DiagnosisCode.LAG, tuple(range(ny)), tuple(names[i] for i in columns),
                                          "shift", change, int(m)))
    terms = [(name, signals[:, i]) for i, name in enumerate(names)]
    terms += [(f"{name}^2", signals[:, i] ** 2) for i, name in enumerate(names)]
    if len(names) <= MAX_PRODUCT_SIGNALS:
        terms += [(f"{names[a]}*{names[b]}", signals[:, a] * signals[:, b])
                  for a in range(len(names)) for b in range(a + 1, len(names))]
    for j in range(ny):
        out += [_Candidate(DiagnosisCode.TERM, (j,), (), term, values[:, None]) for term, values in terms
                if np.ptp(values) > 0]
    return out


def _fitted_candidate(weighted: np.ndarray, basis: np.ndarray, regressor: np.ndarray):
    """The regressor's coefficient fitted beside ``basis`` (orthonormal, sample-major) to the weighted
    residuals: ``(value, std, F, p, correction)`` with ``correction`` (N, n_channels) the fit of
    both in weighted units, or None where the regressor lies in the basis' span."""
    from scipy.special import fdtrc

    shape = weighted.shape
    y, g = weighted.reshape(-1), np.asarray(regressor, dtype=float).reshape(-1)
    y_perp = y - basis @ (basis.T @ y) if basis.size else y
    g_perp = g - basis @ (basis.T @ g) if basis.size else g
    gg = float(g_perp @ g_perp)
    if not np.isfinite(gg) or gg <= 1e-12 * max(float(g @ g), 1e-300):
        return None
    value = float(g_perp @ y_perp) / gg
    left = y_perp - value * g_perp
    rss, dof = float(left @ left), y.size - basis.shape[1] - 1
    if rss <= 0 or dof < 1:
        return None
    s2 = rss / dof
    F = value**2 * gg / s2
    return value, float(np.sqrt(s2 / gg)), F, float(fdtrc(1, dof, F)), (y - left).reshape(shape)
