"""The outputs of a dynamic model and their first derivatives at every sample, for Gauss-Newton.

Flight-test output error (summary Sec. 5.2, Eq. 5.8-5.9) needs the predicted outputs
``y_k(theta)`` and their sensitivities ``dy_k/dtheta`` only: the first-order forward
sensitivities of the states through the same RK4 step as the simulation
(:func:`casest.backend.output_error.state_jets`, order 1), then the output equation's
Jacobian per sample. One compiled pass over the record returns both; the sums that
Gauss-Newton needs are BLAS products outside.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .._casadi.numerics import compile_function, evaluate
from .._casadi.memory import StructureCache
from ..models.dynamic import DynamicModel
from .output_error import dynamic_data_views, dynamic_indices, simulate_jets, state_jets


__all__ = ["OutputSensitivities", "output_sensitivities"]


class OutputSensitivities:
    """``theta -> (y_k, dy_k/dtheta)`` for every sample of a record of a dynamic model.

    Parameters
    ----------
    model : DynamicModel
    n_samples : int
        N.
    masked : bool
        The layout of the data vector (:meth:`casest.Problem.data_vector`): with a mask the
        outputs are ``[z; m]`` per sample. The outputs are not read here.
    jit : bool
        Compile the step and the per-sample output Jacobian to C.
    jit_flags : tuple of str
    """

    def __init__(self, model: DynamicModel, n_samples: int, masked: bool = False, jit: bool = False,
                 jit_flags=("-O1",)):
        N, n, ny = n_samples, model.n_parameters, model.n_outputs
        nu = len(model.inputs)
        self.model, self.n_samples = model, N
        D = dynamic_indices(model)
        nz = 2 * ny if masked else ny
        p = ca.MX.sym("data", N + nu * N + nz * N + len(model.initial_from_data))
        Tm, Um, _, d0m = dynamic_data_views(model, N, masked, p)
        theta = ca.MX.sym("theta", n)
        step, initial = state_jets(model, D, 1, jit, jit_flags)
        A = simulate_jets(model, step, initial, D, theta, Tm, Um, d0m, "gn_simulate")
        per_sample = self._output_jacobian(D)
        if jit:
            per_sample = compile_function(per_sample, jit_flags)
        Y, dY = per_sample.map(N)(A, Um, theta)
        if model.output_delays:  # y(t_k - tau) from neighbouring samples, and its slope in tau
            Y, dY = model.output_delays.apply_with_jacobian(Y, dY, theta, model.parameter_names)
        self.function = ca.Function("oe_sensitivities", [theta, p], [Y, dY], ["theta", "p"], ["y", "dy"])
        self._shape = (N, ny, n)

    def _output_jacobian(self, D: list) -> ca.Function:
        """``(aug_k, u_k, theta) -> (y_k, vec(dy_k/dtheta))``: the output equation and its total derivative,
        ``dh/dx S_k`` on the parameters of the dynamics plus ``dh/dtheta``."""
        model = self.model
        n, nx, nu = model.n_parameters, model.n_states, len(model.inputs)
        aug, u, theta = ca.SX.sym("aug", nx + nx * len(D)), ca.SX.sym("u", nu), ca.SX.sym("theta", n)
        x, S = aug[:nx], ca.reshape(aug[nx:], nx, len(D))
        y = model.output_model.function(ca.vertcat(x, u), theta)
        dy = ca.jacobian(y, theta)
        if D:
            through_states = ca.mtimes(ca.jacobian(y, x), S)
            dy = dy + ca.horzcat(*[through_states[:, D.index(i)] if i in D else ca.SX.zeros(y.numel(), 1)
                                   for i in range(n)])
        return ca.Function("oe_output_jacobian", [aug, u, theta], [y, ca.cse(ca.vec(dy))], ["aug", "u", "theta"],
                           ["y", "dy"])

    def __call__(self, theta, p) -> tuple[np.ndarray, np.ndarray]:
        """The predicted outputs and their Jacobian at ``theta`` (physical units).

        Parameters
        ----------
        theta : array_like, shape (n_parameters,)
        p : ndarray
            The data vector (:meth:`casest.Problem.data_vector`).

        Returns
        -------
        y : ndarray, shape (N, n_outputs)
        jacobian : ndarray, shape (N, n_outputs, n_parameters)
            ``dy_kj / dtheta_i`` (unit of output j per unit of parameter i).
        """
        N, ny, n = self._shape
        Y, dY = evaluate(self.function, np.asarray(theta, dtype=float), p)
        return Y.T, dY.T.reshape(N, n, ny).transpose(0, 2, 1)


_SENSITIVITIES = StructureCache()


def output_sensitivities(model: DynamicModel, n_samples: int, masked: bool = False, jit: bool = False,
                         jit_flags=("-O1",)) -> OutputSensitivities:
    """Cached :class:`OutputSensitivities` for (model, N, masked, jit)."""
    key = (n_samples, bool(masked), bool(jit), tuple(jit_flags))
    cache = _SENSITIVITIES.setdefault(model, {})
    if key not in cache:
        cache[key] = OutputSensitivities(model, n_samples, masked, jit, jit_flags)
    return cache[key]
