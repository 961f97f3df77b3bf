"""The measurement-model interface (:class:`Measurement`): what the stages need of a model;
:mod:`casest.problem.measurement` picks the implementation for a model's kind."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..data.dataset import Dataset
from ..models import Model


__all__ = ['Measurement']


class Measurement:
    """The stages' view of a model (base of :class:`StaticMeasurement` and :class:`DynamicMeasurement`).

    Attributes
    ----------
    model : Model or DynamicModel
    simulated : bool
        The outputs go through states simulated from theta (output error): stage 2 solves
        all parameters together (no variable projection), and long records keep their data
        in the graph.
    """

    simulated = False

    def __init__(self, model):
        self.model = model

    @property
    def through_states(self) -> tuple:
        """Parameters that act on the outputs through the states (the rhs or an initial state):
        never linear (xi1). None for a static model."""
        return ()

    @property
    def output_model(self) -> Model:
        """The static model of the output equation (signals: the states, then the inputs, for
        a dynamic model)."""
        return self.model

    def check_data(self, data: Dataset) -> None:
        """Raise a :class:`casest.DataError` if ``data`` do not fit the model.

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        None
        """
        data.check_model(self.model)

    def prefetch_hessian(self, n_samples: int) -> bool:
        """Start compiling, in the background, what the exact cost Hessian of N samples will need
        (nothing for a static model: its sums compile in a fraction of a second).

        Parameters
        ----------
        n_samples : int

        Returns
        -------
        bool
            Whether a compile was started.
        """
        return False

    def residual_expression(self, n_samples: int, theta, p, masked: bool) -> tuple:
        """The residuals at ``theta`` as CasADi expressions of the data vector ``p``.

        Returns
        -------
        residuals : casadi.MX, shape (n_outputs, N)
            ``z - h``, 0 where an output was not measured.
        outputs : casadi.MX, shape (n_outputs, N)
            z, 0 where not measured.
        counts : casadi.MX, shape (n_outputs, 1)
            The number of measurements N_j of each output.

        Parameters
        ----------
        n_samples : int
        theta : casadi.MX, shape (n_parameters, 1)
        p : casadi.MX
            The data vector.
        masked : bool
        """
        predictions, Z = self._prediction_expression(n_samples, theta, p, masked)
        ny = self.model.n_outputs
        if not masked:
            return Z - predictions, Z, ca.DM.ones(ny) * n_samples
        z, mask = Z[:ny, :], Z[ny:, :]
        return (z - predictions) * mask, z, ca.sum2(mask)

    def _outputs_from(self, Z: np.ndarray, masked: bool) -> np.ndarray:
        """Outputs (N, n_outputs) from the data vector's block, NaN where the mask says not measured."""
        ny = self.model.n_outputs
        return np.where(Z[:, ny:] > 0, Z[:, :ny], np.nan) if masked else Z

    def outputs_of(self, data: Dataset, masked: bool) -> np.ndarray:
        """The outputs as they enter the data vector, shape (N, n_outputs), or (N, 2 n_outputs)
        with ``masked``: z with 0 where not measured, then the mask.

        Parameters
        ----------
        data : Dataset
        masked : bool

        Returns
        -------
        ndarray
        """
        return np.hstack([data.filled_outputs(), data.output_mask()]) if masked else data.outputs
