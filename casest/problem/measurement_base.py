"""The measurement-model interface (:class:`Measurement`): what the stages need of a model;
:mod:`casest.problem.measurement` picks the implementation for a model's kind."""

from __future__ import annotations

import abc

import casadi as ca
import numpy as np

from ..data.dataset import Dataset
from ..backend.noise_terms import NoiseTerm
from ..backend.sums import Record
from ..models import Model


__all__ = ['Measurement']


class Measurement(abc.ABC):
    """The stages' view of a model (base of :class:`StaticMeasurement` and :class:`DynamicMeasurement`).

    Attributes
    ----------
    model : Model or DynamicModel
    simulated : bool
        The outputs go through states simulated from theta (output error): stage 2 solves
        all parameters together (no variable projection), and long records keep their data
        in the graph.
    full_mode_reason : str or None
        Why stage 2 of this kind must solve every parameter together (the full mode), in
        words for a note; None when the reduced and alternating modes apply.
    """

    simulated = False
    full_mode_reason: str | None = None

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

    # -- what each kind of model implements ------------------------------------------------
    @property
    @abc.abstractmethod
    def controlled_names(self) -> tuple:
        """The signals an experiment designer chooses: all of a static model's signals."""

    @abc.abstractmethod
    def controlled_history(self, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        """Their values, shape (n, N), and the samples' positions (a static model: the sample index).

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        history : ndarray, shape (n, N)
        positions : ndarray, shape (N,)
        """

    @abc.abstractmethod
    def information_arguments(self, history, times, data: Dataset) -> dict:
        """The data arguments of :func:`casest.design.information_function` for a signal history.

        Parameters
        ----------
        history : ndarray, shape (n, N)
            The controlled signals (:meth:`controlled_history`).
        times : ndarray, shape (N,)
        data : Dataset

        Returns
        -------
        dict of str to ndarray
        """

    @abc.abstractmethod
    def stack_experiments(self, experiments, separate_noise: bool) -> tuple:
        """Several experiments sharing the parameters as one model and data set
        (:func:`casest.problem.experiments.stack_experiments`).

        Parameters
        ----------
        experiments : mapping of str to Dataset
        separate_noise : bool
            One R per experiment.

        Returns
        -------
        model : Model or DynamicModel
        data : Dataset
        """

    @abc.abstractmethod
    def predict(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        """Noise-free outputs at the data's samples, shape (N, n_outputs).

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset

        Returns
        -------
        ndarray, shape (N, n_outputs)
        """

    @abc.abstractmethod
    def signals_at(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        """The per-sample inputs of :attr:`cost_model`, shape (N, n_signals): the data's signals.

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset

        Returns
        -------
        ndarray
        """

    @property
    @abc.abstractmethod
    def cost_model(self) -> Model:
        """The static model whose per-sample sums, fed :meth:`signals_at`, give the cost: the output equation."""

    @abc.abstractmethod
    def prediction_and_jacobian(self, theta: np.ndarray, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        """h, shape (N * n_outputs,), and dh/dtheta, shape (N * n_outputs, n_parameters), sample-major.

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset

        Returns
        -------
        h : ndarray, shape (N n_outputs,)
        J : ndarray, shape (N n_outputs, n_parameters)
        """

    @abc.abstractmethod
    def prediction_blocks(self, theta: np.ndarray, data: Dataset, block_samples: int):
        """:meth:`prediction_and_jacobian` over consecutive blocks of samples, with each block's
        observation mask, so that what a caller sums over the record never holds it all at once
        (a dynamic model: one block, the whole record, whose states depend on all of it).

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset
        block_samples : int
            Samples per block (the last may be shorter).

        Returns
        -------
        iterator of (h, J, mask)
            Sample-major over the block: h (n n_outputs,), J (n n_outputs, n_parameters), mask
            (n n_outputs,) 1 where the output is measured.
        """

    @abc.abstractmethod
    def jacobian(self, theta: np.ndarray, data: Dataset) -> np.ndarray:
        """dh/dtheta at every sample, shape (N * n_outputs, n_parameters), sample-major.

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)
            Physical units.
        data : Dataset

        Returns
        -------
        ndarray, shape (N n_outputs, n_parameters)
        """

    @abc.abstractmethod
    def data_vector(self, data: Dataset, masked: bool) -> np.ndarray:
        """The NLP parameter ``[vec(X); vec(Z)]`` (sample by sample; ``masked``: Z carries the mask).

        Parameters
        ----------
        data : Dataset
        masked : bool

        Returns
        -------
        ndarray
        """

    @abc.abstractmethod
    def dataset_from_vector(self, p, n_samples: int, masked: bool) -> Dataset:
        """Inverse of :meth:`data_vector`: the data set of a data vector.

        Parameters
        ----------
        p : array_like
            A data vector (:meth:`data_vector`).
        n_samples : int
        masked : bool

        Returns
        -------
        Dataset
        """

    @abc.abstractmethod
    def data_outside_graph(self, n_samples: int) -> bool:
        """Long records keep their data outside the CasADi graph (:func:`casest.backend.sums.data_outside_graph`).

        Parameters
        ----------
        n_samples : int

        Returns
        -------
        bool
        """

    @abc.abstractmethod
    def record(self, data: Dataset, masked: bool) -> Record:
        """The data as a :class:`casest.backend.sums.Record` of (X, Z) for the bound sums.

        Parameters
        ----------
        data : Dataset
        masked : bool

        Returns
        -------
        Record
        """

    @abc.abstractmethod
    def cost_expression(self, n_samples: int, theta, noise, p, masked: bool, noise_term: NoiseTerm, penalty) -> ca.MX:
        """J of paper Eq. 6 as a CasADi expression (:func:`ml_cost_expression`).

        Parameters
        ----------
        n_samples : int
        theta : casadi.MX, shape (n_parameters, 1)
        noise : casadi.MX
            The noise block (``ln R`` or the log-Cholesky vector).
        p : casadi.MX
            The data vector.
        masked : bool
        noise_term : NoiseTerm
            R's parametrisation (:mod:`casest.backend.noise_terms`).
        penalty : GaussianPenalty or None

        Returns
        -------
        casadi.MX
        """

    @abc.abstractmethod
    def information_expression(self, n_samples: int, noise_term: NoiseTerm, theta: ca.MX) -> tuple[list, ca.MX]:
        """The named inputs (signals, R, weights) and the Fisher information ``sum_k w_k J_k' R^-1 J_k``
        over N samples as an MX expression of them and ``theta`` (:func:`casest.design.information_function`).

        Parameters
        ----------
        n_samples : int
        noise_term : NoiseTerm
            R's parametrisation: the shape of the input ``R`` and how it weighs the Jacobian.
        theta : casadi.MX, shape (n_parameters, 1)

        Returns
        -------
        inputs : list of casadi.MX
        information : casadi.MX, shape (n_parameters, n_parameters)
        """

    @abc.abstractmethod
    def cost_hessian(self, n_samples: int, masked: bool, noise_term: NoiseTerm, threads=None, jit=False,
                     jit_flags=("-O2",)) -> ca.Function:
        """``(theta, noise vector, data) -> (J, H)`` from the per-sample sums (see :meth:`Problem.cost_hessian`).

        Parameters
        ----------
        n_samples : int
        masked : bool
        noise_term : NoiseTerm
            R's parametrisation (the noise block's length and cost).
        threads : int, optional
        jit : bool
        jit_flags : tuple of str

        Returns
        -------
        casadi.Function
        """

    @abc.abstractmethod
    def ml_sums(self, n_samples: int, scale, threads, jit, jit_flags, masked: bool, noise_term: NoiseTerm):
        """The compiled per-sample sums of J/N (:class:`casest.backend.sums.MLSums`).

        Parameters
        ----------
        n_samples : int
        scale : array_like, shape (n_parameters,)
        threads : int or None
        jit : bool
        jit_flags : tuple of str
        masked : bool
        noise_term : NoiseTerm

        Returns
        -------
        MLSums
        """

    @abc.abstractmethod
    def cost_sums(self, n_samples: int, masked: bool, noise_term: NoiseTerm, bound: bool) -> tuple:
        """The sums :meth:`casest.Problem.cost` evaluates J/N with, and the scale of their theta.

        Parameters
        ----------
        n_samples : int
        masked : bool
        noise_term : NoiseTerm
        bound : bool
            The data outside the graph (:func:`casest.backend.sums.data_outside_graph`).

        Returns
        -------
        sums : MLSums
            Of :attr:`cost_model`, in ``w = [theta / scale; noise vector]``.
        scale : ndarray, shape (n_parameters,)
        """
