"""The interface of a noise model (:class:`NoiseModel`): what the stages ask of how R enters the
ML cost; :mod:`casest.problem.noise` holds the three noise models."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..backend.linalg import variances_of
from ..backend.noise_terms import DIAGONAL, NoiseTerm
from ..models import Model


__all__ = ["NoiseModel"]


class NoiseModel:
    """How the noise covariance R enters the ML cost (base of the three noise models).

    Attributes
    ----------
    kind : str
        A label for reports and saved results (``"diagonal"``, ``"known"``, ``"full"``);
        code decides with the attributes below, never with this label.
    estimated : bool
        R is estimated with theta (False: R is given and held).
    term : NoiseTerm
        R's parametrisation in the cost, the sums and the information matrix
        (:mod:`casest.backend.noise_terms`: diagonal ``ln R`` or log-Cholesky).
    """

    kind = ""
    estimated = True
    term: NoiseTerm = DIAGONAL

    @property
    def profiled_per_channel(self) -> bool:
        """R is estimated and its ML value at theta is each channel's residual mean square (paper
        Eq. 6 with R unknown and diagonal): what stage 1's ranking and error bracket, and the
        two-stage derivatives, assume."""
        return self.estimated and self.term.per_channel

    def bind(self, model: Model) -> "NoiseModel":
        """Check the noise model against a model's outputs; returns itself.

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        NoiseModel

        Raises
        ------
        OptionError
            Outputs named that the model does not have, or outputs without a given noise.
        """
        return self

    def given_variances(self, model: Model) -> np.ndarray | None:
        """The given diagonal of R, shape (n_outputs,), or None when R is estimated.

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        ndarray, shape (n_outputs,), or None
        """
        return None

    def for_experiments(self, output_names, experiments) -> "NoiseModel":
        """The noise model of several experiments with one R each (outputs ``output@experiment``).

        Parameters
        ----------
        output_names : sequence of str
            The declared outputs.
        experiments : sequence of str
            The experiments' names.

        Returns
        -------
        NoiseModel
        """
        return self

    def for_declared_outputs(self, output_names, experiments) -> "NoiseModel":
        """Inverse of :meth:`for_experiments` where it exists (the same noise in every experiment).

        Parameters
        ----------
        output_names : sequence of str
        experiments : sequence of str

        Returns
        -------
        NoiseModel
        """
        return self

    def vector_size(self, n_outputs: int) -> int:
        """Length of the noise block of stage 2's decision vector (``ln R_j``: n_outputs).

        Parameters
        ----------
        n_outputs : int

        Returns
        -------
        int
        """
        return self.term.block_size(n_outputs)

    def to_vector(self, R) -> np.ndarray:
        """The noise block for R: ``ln R_j`` of the diagonal R, shape (n_outputs,).

        Parameters
        ----------
        R : array_like, shape (n_outputs,) (a full R: (n_outputs, n_outputs))

        Returns
        -------
        ndarray, shape (vector_size(n_outputs),)
        """
        return self.term.block_of(R)

    def from_vector(self, vector, n_outputs: int) -> np.ndarray:
        """Inverse of :meth:`to_vector`: the diagonal of R, shape (n_outputs,), or the full R.

        Parameters
        ----------
        vector : array_like, shape (vector_size(n_outputs),)
        n_outputs : int

        Returns
        -------
        ndarray, shape (n_outputs,) (a full R: (n_outputs, n_outputs))
        """
        return self.term.covariance_of_block(vector, n_outputs)

    def profile(self, problem, theta) -> np.ndarray:
        """The R that minimises J at ``theta`` (the known R when R is given).

        Parameters
        ----------
        problem : Problem
        theta : mapping or array_like

        Returns
        -------
        ndarray, shape (n_outputs,) (a full R: (n_outputs, n_outputs))
        """
        return np.maximum(problem.residual_mean_square(theta), 1e-300)

    def start(self, problem, theta0, floor: np.ndarray, R0=None) -> np.ndarray:
        """Where stage 2 starts R: ``R0`` if given, else the ML R at ``theta0``, held above ``floor``.

        Parameters
        ----------
        problem : Problem
        theta0 : mapping or array_like
        floor : ndarray, shape (n_outputs,)
            Lower bounds of the variances.
        R0 : array_like, optional

        Returns
        -------
        ndarray, shape (n_outputs,) (a full R: (n_outputs, n_outputs))
        """
        R = problem.residual_mean_square(theta0) if R0 is None else np.asarray(R0, dtype=float).reshape(-1)
        return np.maximum(R, floor)

    def stage2_bounds(self, floor: np.ndarray, R0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the noise block in stage 2 (``ln R_j >= ln floor_j``).

        Parameters
        ----------
        floor : ndarray, shape (n_outputs,)
        R0 : ndarray
            The start (a held R is bounded to it).

        Returns
        -------
        lower, upper : ndarray, shape (vector_size(n_outputs),) each
        """
        return np.log(floor), np.full(floor.size, np.inf)

    def decision_bounds(self, floor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the noise variables of an embedded NLP (:meth:`symbols`), which leaves out a held R.

        Parameters
        ----------
        floor : ndarray, shape (n_outputs,)

        Returns
        -------
        lower, upper : ndarray
        """
        return self.stage2_bounds(floor, None)

    def decision_vector(self, R) -> np.ndarray:
        """The noise variables of an embedded NLP (:meth:`symbols`) for R; empty when R is held.

        Parameters
        ----------
        R : array_like, shape (n_outputs,) (a full R: (n_outputs, n_outputs))

        Returns
        -------
        ndarray
        """
        return self.to_vector(R)

    def decision_covariance(self, variables, model: Model) -> np.ndarray:
        """Inverse of :meth:`decision_vector`: R from the noise variables (a held R: the given one).

        Parameters
        ----------
        variables : array_like
        model : Model or DynamicModel

        Returns
        -------
        ndarray, shape (n_outputs,) (a full R: (n_outputs, n_outputs))
        """
        return self.from_vector(variables, model.n_outputs)

    def cost_block(self, variables, model: Model):
        """The noise block the cost takes, from the noise variables of an embedded NLP (a held R: its
        fixed block, whatever the variables).

        Parameters
        ----------
        variables : casadi.MX
        model : Model or DynamicModel

        Returns
        -------
        casadi.MX or casadi.DM
        """
        return variables

    def symbols(self, model: Model) -> tuple:
        """The noise part of an embedded NLP: ``(vector, variables, R)`` where ``vector`` enters
        the sums, ``variables`` is the decision block (None when R is held) and ``R`` the
        covariance expression (diagonal: a column).

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        vector : casadi.MX
        variables : casadi.MX or None
        R : casadi.MX
        """
        rho = ca.MX.sym("rho", model.n_outputs)
        return rho, rho, ca.exp(rho)

    def start_expression(self, variances, floor):
        """The decision block's start for variances ``max(variances, floor)`` as CasADi
        expressions (column vectors of length n_outputs), or None when R is held.

        Parameters
        ----------
        variances : casadi.MX, shape (n_outputs, 1)
        floor : casadi.MX, shape (n_outputs, 1)

        Returns
        -------
        casadi.MX or None
        """
        return ca.log(ca.fmax(variances, floor))

    def bounds_expression(self, floor) -> tuple:
        """:meth:`decision_bounds` for a floor given as a CasADi expression.

        Parameters
        ----------
        floor : casadi.MX, shape (n_outputs, 1)

        Returns
        -------
        lower, upper : casadi.MX or casadi.DM
        """
        return ca.log(floor), ca.DM.inf(floor.numel())

    def variable_names(self, output_names) -> list:
        """Names of the decision variables of :meth:`symbols`.

        Parameters
        ----------
        output_names : sequence of str

        Returns
        -------
        list of str
        """
        return [f"ln_R[{c}]" for c in output_names]

    def floor_constraint(self, variables, floor):
        """The noise floor as a constraint expression ``>= 0`` on the decision block, or None.

        Parameters
        ----------
        variables : casadi.MX
            The decision block of :meth:`symbols`.
        floor : casadi.MX, shape (n_outputs, 1)

        Returns
        -------
        casadi.MX or None
        """
        return variables - floor

    def stage1_weights(self, model: Model) -> np.ndarray | None:
        """Per-output weights applied to outputs and residuals in stage 1 (None: unweighted).

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        ndarray, shape (n_outputs,), or None
        """
        return None

    def check_data(self, data) -> None:
        """Refuse data the noise model cannot take (a full R needs every output at every sample).

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        None

        Raises
        ------
        DataError
            Data this noise model cannot take.
        """

    def solved_covariance(self, R_start: np.ndarray, R_solved: np.ndarray) -> np.ndarray:
        """The R a stage-2 solve reports (a held R: the given one exactly, not its round trip
        through the decision vector).

        Parameters
        ----------
        R_start : ndarray
            The R stage 2 started from (:meth:`start`).
        R_solved : ndarray
            The R of the solve's end point.

        Returns
        -------
        ndarray
        """
        return R_solved

    def stage2_mode(self, mode: str) -> str:
        """The stage-2 mode that solves with this noise model what ``mode`` asks for.

        Parameters
        ----------
        mode : {"full", "reduced", "alternating"}

        Returns
        -------
        str
            ``mode`` (a known R: ``"reduced"`` for ``"alternating"``, there is no R to alternate).
        """
        return mode

    def std_covariance(self, R) -> np.ndarray:
        """R at the estimate as the standard deviations take it, checked.

        Parameters
        ----------
        R : array_like, shape (n_outputs,), or (n_outputs, n_outputs)

        Returns
        -------
        ndarray
            The variances, shape (n_outputs,) (a full R given: its diagonal); a full noise
            model: the full R.

        Raises
        ------
        OptionError
            A full noise model given variances only.
        """
        return variances_of(R)

    def floor_channels(self, r_at_floor, n_outputs: int) -> np.ndarray:
        """The channels whose R is at the noise floor (an exact fit), whose variance the std take
        from the residuals instead (NIST's RSS / (N - n/m)).

        Parameters
        ----------
        r_at_floor : array_like of bool, shape (n_outputs,), or None
        n_outputs : int

        Returns
        -------
        ndarray of bool, shape (n_outputs,)
        """
        return np.zeros(n_outputs, dtype=bool) if r_at_floor is None else np.asarray(r_at_floor, dtype=bool)

    def held_rows(self, floor_channels: np.ndarray) -> np.ndarray:
        """Which entries of the noise block the covariance holds fixed (a channel at the floor).

        Parameters
        ----------
        floor_channels : ndarray of bool, shape (n_outputs,)

        Returns
        -------
        ndarray of bool
            One per entry of the noise block (entries past its length are free).
        """
        return floor_channels

    def describe(self, model: Model) -> str:
        """One line for reports.

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        str
        """
        return "unknown diagonal R (estimated)"
