"""The records of a parameter's profile-likelihood interval and of its likelihood-ratio set from the
sweep, as an estimate carries them and its file saves them
(:func:`casest.two_stage.profile.profile_intervals` and
:func:`casest.two_stage.sweep.confidence.confidence_sets` compute them)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["ProfileInterval", "ParameterInterval", "WALD_DIFFERENCE"]

#: the report shows a parameter's profile interval beside its std when an end differs from
#: ``estimate +- z std`` by more than this fraction of ``z std``
WALD_DIFFERENCE = 0.1


@dataclass(frozen=True)
class ProfileInterval:
    """The profile-likelihood interval of one parameter.

    Attributes
    ----------
    name : str
    estimate : float
    lower, upper : float
        The ends (physical units); a bound of the parameter where the set reaches it.
    at_bound : tuple of (bool, bool)
        Whether each end is the parameter's bound.
    level : float
    solves : int
        Constrained solves spent.
    """

    name: str
    estimate: float
    lower: float
    upper: float
    at_bound: tuple
    level: float
    solves: int

    @property
    def asymmetry(self) -> float:
        """``(upper - estimate) / (estimate - lower)``: 1 for a symmetric interval."""
        below = self.estimate - self.lower
        return float((self.upper - self.estimate) / below) if below > 0 else np.inf

    def differs_from_wald(self, std: float, fraction: float = WALD_DIFFERENCE) -> bool:
        """Whether an end differs from ``estimate +- z std`` (z of the same level) by more than
        ``fraction`` of ``z std`` (or the std is not available).

        Parameters
        ----------
        std : float
            The parameter's standard deviation.
        fraction : float

        Returns
        -------
        bool
        """
        from scipy.stats import norm

        half = norm.ppf(0.5 + self.level / 2) * std
        if not np.isfinite(half) or half <= 0:
            return True
        return bool(max(abs(self.estimate - half - self.lower), abs(self.estimate + half - self.upper)) > fraction * half)

    def to_dict(self) -> dict:
        """Plain-Python form for JSON.

        Returns
        -------
        dict
        """
        out = asdict(self)
        out["at_bound"] = list(self.at_bound)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "ProfileInterval":
        """The record of :meth:`to_dict`'s form.

        Parameters
        ----------
        data : dict

        Returns
        -------
        ProfileInterval
        """
        return cls(str(data["name"]), float(data["estimate"]), float(data["lower"]), float(data["upper"]),
                   tuple(bool(b) for b in data["at_bound"]), float(data["level"]), int(data["solves"]))


@dataclass(frozen=True)
class ParameterInterval:
    """The likelihood-ratio confidence set of one xi2 parameter, from the sweep.

    Attributes
    ----------
    name : str
    intervals : tuple of (float, float)
        Disjoint intervals, ascending (physical units).
    resolution : tuple of (float, float)
        Per interval, the largest distance by which its lower and upper ends may miss the
        threshold crossing (the design's spacing there, NaN where the design does not bound it;
        after refinement, the bracket).
    at_bound : tuple of (bool, bool)
        Per interval, whether its ends are the parameter's bounds (the set reaches the box).
    level : float
        Confidence level (NaN where not set).
    """

    name: str
    intervals: tuple
    resolution: tuple
    at_bound: tuple
    level: float = float("nan")

    @property
    def connected(self) -> bool:
        """Whether the set is one interval."""
        return len(self.intervals) == 1

    def to_dict(self) -> dict:
        """Plain-Python form for JSON (non-finite numbers as strings).

        Returns
        -------
        dict
        """
        def number(x):
            return float(x) if np.isfinite(x) else str(float(x))

        return {"name": self.name, "intervals": [[number(a), number(b)] for a, b in self.intervals],
                "resolution": [[number(a), number(b)] for a, b in self.resolution],
                "at_bound": [[bool(a), bool(b)] for a, b in self.at_bound], "level": number(self.level)}

    @classmethod
    def from_dict(cls, data: dict) -> "ParameterInterval":
        """The record of :meth:`to_dict`'s form.

        Parameters
        ----------
        data : dict

        Returns
        -------
        ParameterInterval
        """
        pairs = lambda rows, kind: tuple((kind(a), kind(b)) for a, b in rows)  # noqa: E731
        return cls(str(data["name"]), pairs(data["intervals"], float), pairs(data["resolution"], float),
                   pairs(data["at_bound"], bool), float(data["level"]))
