"""What a model declares, as both kinds of model expose it: its parameters (names, bounds,
nominal values, scales, priors) and the names of its signals and outputs.

:class:`casest.Model` and :class:`casest.DynamicModel` inherit :class:`Declarations`; each
sets ``parameters``, ``signals``, ``output_names`` and ``output_units`` (a dynamic model
takes its parameters and outputs from its output equation, a :class:`casest.Model` it
holds as ``output_model``).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from ..checks import with_suggestion
from ..errors import ModelError
from .priors import Gaussian

__all__ = ["Declarations"]


class Declarations:
    """The parameter table and the signal and output names of a model (base of both kinds).

    Attributes
    ----------
    parameters : tuple of Parameter
    signals : tuple of Signal
    output_names, output_units : tuple of str
    """

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def signal_names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.signals)

    @property
    def n_parameters(self) -> int:
        return len(self.parameters)

    @property
    def n_signals(self) -> int:
        return len(self.signals)

    @property
    def n_outputs(self) -> int:
        return len(self.output_names)

    @property
    def lower_bounds(self) -> np.ndarray:
        """Lower bounds, shape (n_parameters,)."""
        return np.array([p.lb for p in self.parameters], dtype=float)

    @property
    def upper_bounds(self) -> np.ndarray:
        """Upper bounds, shape (n_parameters,)."""
        return np.array([p.ub for p in self.parameters], dtype=float)

    @property
    def nominal(self) -> np.ndarray:
        """Nominal values, shape (n_parameters,)."""
        return np.array([p.nominal for p in self.parameters], dtype=float)

    @property
    def scales(self) -> np.ndarray:
        """Typical magnitudes used to scale the NLP, shape (n_parameters,)."""
        return np.array([p.typical_scale for p in self.parameters], dtype=float)

    def index(self, names: Sequence[str] | str) -> list[int]:
        """Positions of parameter names; raises with a suggestion for unknown names.

        Parameters
        ----------
        names : str or sequence of str

        Returns
        -------
        list of int

        Raises
        ------
        ModelError
            An unknown name (with a "did you mean").
        """
        if isinstance(names, str):
            names = [names]
        out = []
        for n in names:
            if n not in self.parameter_names:
                raise ModelError(f"unknown parameter {with_suggestion(n, self.parameter_names)}; the model's "
                                 f"parameters are {list(self.parameter_names)}")
            out.append(self.parameter_names.index(n))
        return out

    def vector(self, values: Mapping[str, float] | Sequence[float] | np.ndarray) -> np.ndarray:
        """Parameter values as a vector of shape (n_parameters,) in model order.

        A mapping must name every parameter; unknown names raise :class:`ModelError`.

        Parameters
        ----------
        values : mapping of str to float, or array_like, shape (n_parameters,)

        Returns
        -------
        ndarray, shape (n_parameters,)
        """
        if isinstance(values, Mapping):
            self.index(list(values))
            missing = [n for n in self.parameter_names if n not in values]
            if missing:
                raise ModelError(f"values for parameter(s) {missing} are missing")
            return np.array([float(values[n]) for n in self.parameter_names])
        arr = np.asarray(values, dtype=float).reshape(-1)
        if arr.size != self.n_parameters:
            raise ModelError(
                f"expected {self.n_parameters} parameter values "
                f"{list(self.parameter_names)}, got {arr.size}"
            )
        return arr

    def gaussian_prior_terms(self) -> tuple[np.ndarray, np.ndarray]:
        """Means and precisions (1/std^2) of the parameters' Gaussian priors, shape (n_parameters,) each.

        Parameters without a Gaussian prior get precision 0. Used when the priors enter the
        cost as penalties ``(theta - mean)^2 / (2 std^2)`` (MAP estimation).

        Returns
        -------
        mean, precision : ndarray, shape (n_parameters,) each
        """
        means = np.array([p.prior.mean if isinstance(p.prior, Gaussian) else 0.0 for p in self.parameters])
        precisions = np.array([1.0 / p.prior.std**2 if isinstance(p.prior, Gaussian) else 0.0 for p in self.parameters])
        return means, precisions
