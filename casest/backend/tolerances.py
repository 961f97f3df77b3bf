"""Tolerances that several solvers and checks share, defined once."""

from __future__ import annotations

__all__ = ["cost_tolerance"]


def cost_tolerance(cost: float) -> float:
    """Cost difference below which two ML costs count as equal (round-off of the solves).

    Parameters
    ----------
    cost : float
        The cost compared against (its magnitude sets the tolerance).

    Returns
    -------
    float
        ``1e-9 * max(1, |cost|)``.
    """
    return 1e-9 * max(1.0, abs(cost))
