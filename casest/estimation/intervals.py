"""The record of a parameter's profile-likelihood interval, as an estimate carries it and its file
saves it (:func:`casest.estimation.profile.profile_intervals` computes it)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["ProfileInterval", "WALD_DIFFERENCE"]

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
