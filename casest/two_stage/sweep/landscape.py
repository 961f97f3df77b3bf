"""The result of stage 1: candidates, their least-squares xi1, R and ranking, the minima and the verdict."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from .error_bound import ErrorBound
from ...options import SweepCriterion


__all__ = ["Deferred", "Landscape"]


class Deferred:
    """A value computed on first read: give it to a :class:`Landscape` field that accepts one
    (``error_bound``), and the field runs ``compute()`` the first time it is read.

    Parameters
    ----------
    compute : callable
        ``compute() -> value``; it may hold what it needs (an evaluator, the data) until then.
    """

    def __init__(self, compute):
        self.compute = compute


class _ComputedOnFirstRead:
    """The descriptor of a dataclass field that may hold a :class:`Deferred` (its default: None)."""

    def __set_name__(self, owner, name):
        self._slot = "_" + name

    def __get__(self, obj, owner=None):
        if obj is None:
            return None  # the field's default, as dataclasses ask for it
        value = obj.__dict__.get(self._slot)
        if isinstance(value, Deferred):
            value = value.compute()
            obj.__dict__[self._slot] = value
        return value

    def __set__(self, obj, value):
        obj.__dict__[self._slot] = value


@dataclass
class Landscape:
    """What the stage-1 sweep found.

    Attributes
    ----------
    nonlinear : tuple of str
        Names of xi2 (columns of ``candidates``).
    linear : tuple of str
        Names of xi1 (columns of ``xi1``).
    output_names : tuple of str
        Channels (columns of ``R``).
    candidates : ndarray, shape (M, n2)
        Swept xi2 values, physical units.
    xi1 : ndarray, shape (M, n1)
        Least-squares xi1 at each candidate (NaN where A was rank-deficient).
    R : ndarray, shape (M, n_outputs)
        Per-channel residual mean square at each candidate.
    trace_R : ndarray, shape (M,)
        ``Tr[R(xi2)]`` (paper Eq. 19); ``inf`` where A was rank-deficient.
    best_index : int
        Candidate with the smallest ranking value (``Tr[R]`` by default).
    local_minima : ndarray of int
        Candidates that are local minima of the ranking among their neighbours, best first.
    competing : ndarray of int
        Local minima in a separate basin that fit statistically as well as the best.
    verdict : str
        One of :data:`VERDICTS`.
    reason : str
        The verdict's reason in words.
    recommended_mode : str
        The stage-2 mode ``casest.estimate(mode="auto")`` uses: ``"reduced"`` when there
        are linear and nonlinear parameters, else ``"full"`` (a failed or climbing solve is
        repeated in the other mode).
    design : str
        The design actually used.
    grid_shape : tuple of int or None
        Grid dimensions when ``design == "grid"``.
    linearization_ratio : float or None
        Left-hand side of Eq. 17 at the best candidate.
    curvature_min_eig : float or None
        Smallest eigenvalue of the normalised profile Gauss-Newton matrix (Eq. 18).
    n_samples : int
        N of the data swept.
    seconds : float
        Wall time of the sweep.
    nominal_xi1, nominal_R : ndarray or None
        Least-squares xi1 and R at the parameters' nominal xi2 (evaluated beside the
        design; ``None`` when nothing is swept).
    n_design : int or None
        The first ``n_design`` candidates are the design (``grid_shape`` applies to them);
        the rest were added by local refinement around the best candidate. ``None``: all.
    flat_spread : float or None
        One-sigma interval of the worst-determined xi2 combination, in prior-CDF units
        (the absolute flatness test).
    criterion : str
        What ranked the candidates (:attr:`SweepSettings.criterion`).
    ranking : ndarray, shape (M,) or None
        The ranked values (``Tr[R]``, or the profile ML cost for ``"likelihood"``).
    error_bound : ErrorBound or None
        The paper's cost error E, the bracket of Eq. 7 and Eq. 17-18 as printed
        (:attr:`SweepSettings.error_bound`); ``None`` when not computed. The sweep leaves it
        to be computed the first time it is read (a report, :meth:`to_dict`, a pickle): one more
        pass over every candidate that a fit nobody inspects does not pay for.
    nominal_in_best_basin : bool or None
        Whether steepest descent over the design, from the candidate nearest the nominal xi2
        (prior-probability coordinates), ends at the best design candidate: stage 1's evidence
        that the nominal values lie in the best candidate's basin. None when not judged (nothing
        swept, or that candidate is not a fit).
    in_set : ndarray of bool, shape (M,), or None
        The candidates of the paper's set S_xi2 (:attr:`SweepSettings.radius`,
        :attr:`SweepSettings.validity` ``"every"``): only they compete for the best; None when
        every candidate does.
    unresolved : ndarray of int, shape (K,), or None
        The further local minima (after the best, up to
        :data:`casest.two_stage.sweep.resolution.FURTHER_MINIMA_CHECKED`, Tr[R] within
        :data:`~casest.two_stage.sweep.resolution.UNRESOLVED_TRACE_RATIO` times the best's) at
        which the paper's Eq. 17 fails over their own half sampling step: there the design does
        not resolve the landscape, a deeper minimum may lie between its candidates, and stage-2
        starts that agree are no evidence that their minimum is global. Empty when every checked minimum is
        resolved or the design is scattered (checked on grids only:
        :mod:`casest.two_stage.sweep.resolution`); None in a landscape saved by an earlier
        version.
    """

    nonlinear: tuple
    linear: tuple
    output_names: tuple
    candidates: np.ndarray
    xi1: np.ndarray
    R: np.ndarray
    trace_R: np.ndarray
    best_index: int
    local_minima: np.ndarray
    competing: np.ndarray
    verdict: str
    reason: str
    recommended_mode: str
    design: str
    grid_shape: tuple | None
    linearization_ratio: float | None
    curvature_min_eig: float | None
    n_samples: int
    seconds: float = 0.0
    nominal_xi1: np.ndarray | None = None
    nominal_R: np.ndarray | None = None
    n_design: int | None = None
    flat_spread: float | None = None
    criterion: SweepCriterion = "trace"
    ranking: np.ndarray | None = None
    error_bound: ErrorBound | None = _ComputedOnFirstRead()
    nominal_in_best_basin: bool | None = None
    in_set: np.ndarray | None = None
    unresolved: np.ndarray | None = None

    def __post_init__(self):
        if self.ranking is None:
            self.ranking = self.trace_R

    def __getstate__(self) -> dict:
        # a deferred bound is computed before the landscape leaves the process (it holds an evaluator)
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def __setstate__(self, state: dict) -> None:
        for name, value in state.items():
            setattr(self, name, value)

    @property
    def best_xi2(self) -> np.ndarray:
        """xi2 of the best candidate, shape (n2,)."""
        return self.candidates[self.best_index].copy()

    @property
    def best_xi1(self) -> np.ndarray:
        """xi1 of the best candidate, shape (n1,)."""
        return self.xi1[self.best_index].copy()

    @property
    def best_R(self) -> np.ndarray:
        """R of the best candidate, shape (n_outputs,)."""
        return self.R[self.best_index].copy()

    def summary(self) -> str:
        """A few lines for the report.

        Returns
        -------
        str
        """
        lines = [
            f"verdict: {self.verdict}",
            f"reason: {self.reason}",
            f"design: {self.design}, {len(self.trace_R)} candidates, N = {self.n_samples}",
        ]
        if self.nonlinear:
            best = ", ".join(f"{n} = {v:.6g}" for n, v in zip(self.nonlinear, self.best_xi2))
            ranked = "" if self.criterion == "trace" else f"; profile ML cost {self.ranking[self.best_index]:.10g}"
            lines.append(f"best candidate: {best}; Tr[R] = {self.trace_R[self.best_index]:.6g}{ranked}")
            lines.append(
                f"local minima: {len(self.local_minima)}, competing: {len(self.competing)}"
            )
        if self.linearization_ratio is not None:
            lines.append(f"linearisation check (paper Eq. 17): half a sweep step changes the prediction by "
                         f"{self.linearization_ratio:.3g} of its norm")
        if self.curvature_min_eig is not None:
            lines.append(f"curvature check (paper Eq. 18): smallest normalised eigenvalue {self.curvature_min_eig:.3g}")
        if self.flat_spread is not None:
            lines.append(f"worst-determined xi2 combination: 1-sigma spans {self.flat_spread:.3g} of the swept prior mass")
        if self.error_bound is not None:
            lines += self.error_bound.lines()
        if self.in_set is not None:
            lines.append(f"candidate set (paper Sec. II.C, Step 2): {int(np.count_nonzero(self.in_set))} of "
                         f"{len(self.in_set)} candidates compete")
        if self.unresolved is not None and len(self.unresolved):
            lines.append(f"not resolved (paper Eq. 17 fails over half a step): {len(self.unresolved)} further local "
                         "minimum/minima of the ranking")
        if self.n_design is not None and self.n_design < len(self.trace_R):
            lines.append(f"refined: {len(self.trace_R) - self.n_design} candidates added around the best")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """Plain-Python form for JSON (arrays as nested lists; inf/NaN as strings).

        Returns
        -------
        dict
        """
        from ..._casadi.array_json import encode_array

        out = {}
        for key, value in self.__getstate__().items():
            if isinstance(value, np.ndarray):
                out[key] = encode_array(value)
            elif isinstance(value, ErrorBound):
                out[key] = {k: (v if math.isfinite(v) else str(v)) if isinstance(v, float) else v
                            for k, v in value.__dict__.items()}
            elif isinstance(value, tuple):
                out[key] = list(value)
            else:
                out[key] = value
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "Landscape":
        """The Landscape of :meth:`to_dict`'s form.

        Parameters
        ----------
        data : dict

        Returns
        -------
        Landscape
        """
        from ..._casadi.array_json import decode_array

        kw = dict(data)
        for key in ("candidates", "xi1", "R", "trace_R"):
            kw[key] = decode_array(kw[key], float)
        for key in ("nominal_xi1", "nominal_R", "ranking"):
            if kw.get(key) is not None:
                kw[key] = decode_array(kw[key], float)
        for key in ("local_minima", "competing"):
            kw[key] = decode_array(kw[key], int)
        if kw.get("in_set") is not None:
            kw["in_set"] = decode_array(kw["in_set"], bool)
        if kw.get("unresolved") is not None:
            kw["unresolved"] = decode_array(kw["unresolved"], int)
        for key in ("nonlinear", "linear", "output_names"):
            kw[key] = tuple(kw[key])
        if kw.get("error_bound") is not None:
            kw["error_bound"] = ErrorBound.from_dict(kw["error_bound"])
        if kw.get("grid_shape") is not None:
            kw["grid_shape"] = tuple(kw["grid_shape"])
        return cls(**kw)
