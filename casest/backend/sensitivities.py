"""The outputs of a dynamic model and their first derivatives at every sample, for Gauss-Newton.

Flight-test output error (summary Sec. 5.2, Eq. 5.8-5.9) needs the predicted outputs
``y_k(theta)`` and their sensitivities ``dy_k/dtheta`` only: the first-order forward
sensitivities of the states through the same RK4 step as the simulation
(:func:`casest.backend.output_error.state_jets`, order 1), then the output equation's
Jacobian per sample. One compiled pass over the record returns both; the sums that
Gauss-Newton needs are BLAS products outside. Compiled (``jit``), the pass is one C loop over
the samples (:class:`casest._casadi.record_loop.RecordLoop`: the jet step and the output
Jacobian as one step, the outputs written in place); otherwise, or with output delays, a
CasADi ``mapaccum`` of the step and a ``map`` of the output Jacobian.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .._casadi.evaluation import evaluate
from .._casadi.numerics import compile_function
from .._casadi.memory import StructureCache
from .._casadi.record_loop import RecordLoop
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
        self.model, self.n_samples = model, N
        D = dynamic_indices(model)
        nz = 2 * ny if masked else ny
        self._shape, self._nz = (N, ny, n), nz
        self._loop, self._output_loop, self._last_rows = None, None, None
        if jit and not model.output_delays:
            step, self._initial = state_jets(model, D, 1)
            # the sensitivity bodies' flags: a large step, whose -O3 compile costs seconds for little speed
            self._loop = RecordLoop.build(self._record_step(step, D), widths=(ny, ny * n), optimisation=jit_flags)
            if self._loop is not None:
                step0, self._initial0 = state_jets(model, D, 0)
                self._output_loop = RecordLoop.build(self._output_step(step0, D), optimisation=jit_flags)
        if self._loop is None:
            self.function = self._graph(D, masked, jit, jit_flags)

    @property
    def compiled_loop(self) -> bool:
        """Whether the pass runs as one compiled C loop over the record (else a CasADi graph)."""
        return self._loop is not None

    def _graph(self, D: list, masked: bool, jit: bool, jit_flags) -> ca.Function:
        """``(theta, p) -> (Y, dY)`` as a CasADi graph: the jets' ``mapaccum``, the output Jacobian's ``map``."""
        model, (N, _, n) = self.model, self._shape
        nu = len(model.inputs)
        p = ca.MX.sym("data", N + nu * N + self._nz * N + len(model.initial_from_data))
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
        return ca.Function("oe_sensitivities", [theta, p], [Y, dY], ["theta", "p"], ["y", "dy"])

    def _record_step(self, step: ca.Function, D: list) -> ca.Function:
        """``(aug_k, [u_k; u_a; u_b; dt], theta) -> (aug_k+1, [y_k; vec dy_k])``: one sample of the pass."""
        model = self.model
        nu, n_step_u = len(model.inputs), model.step_function.size1_in(1)
        aug, theta = ca.SX.sym("aug", step.size1_in(0)), ca.SX.sym("theta", model.n_parameters)
        d = ca.SX.sym("d", nu + 2 * n_step_u + 1)
        u, ua, ub, dt = ca.vertsplit(d, [0, nu, nu + n_step_u, nu + 2 * n_step_u, d.numel()])
        theta_D = ca.vertcat(*[theta[i] for i in D]) if D else ca.SX(0, 1)
        y, dy = self._output_jacobian(D)(aug, u, theta)
        return ca.Function("oe_sensitivity_sample", [aug, d, theta],
                           [ca.densify(step(aug, ua, ub, dt, theta_D)), ca.vertcat(y, dy)])

    def _output_step(self, step0: ca.Function, D: list) -> ca.Function:
        """``(x_k, [u_k; u_a; u_b; dt], theta) -> (x_k+1, y_k)``: one sample of the outputs-only pass."""
        model = self.model
        nu, n_step_u = len(model.inputs), model.step_function.size1_in(1)
        x, theta = ca.SX.sym("x", model.n_states), ca.SX.sym("theta", model.n_parameters)
        d = ca.SX.sym("d", nu + 2 * n_step_u + 1)
        u, ua, ub, dt = ca.vertsplit(d, [0, nu, nu + n_step_u, nu + 2 * n_step_u, d.numel()])
        theta_D = ca.vertcat(*[theta[i] for i in D]) if D else ca.SX(0, 1)
        y = model.output_model.function(ca.vertcat(x, u), theta)
        return ca.Function("oe_output_sample", [x, d, theta], [ca.densify(step0(x, ua, ub, dt, theta_D)), y])

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
        theta = np.asarray(theta, dtype=float)
        if self._loop is None:
            Y, dY = evaluate(self.function, theta, p)
            return Y.T, dY.T.reshape(N, n, ny).transpose(0, 2, 1)
        p = np.asarray(p, dtype=float).reshape(-1)
        nu = len(self.model.inputs)
        aug0 = np.asarray(ca.densify(self._initial(theta, p[N + (nu + self._nz) * N:]))).reshape(-1)
        _, (Y, dY) = self._loop(aug0, self._rows(p), theta, keep_accumulators=False)
        return Y, dY.reshape(N, n, ny).transpose(0, 2, 1)

    def outputs(self, theta, p) -> np.ndarray:
        """The predicted outputs alone at ``theta``, shape (N, n_outputs): a compiled pass of the states
        without their sensitivities (a trial point's cost), else the outputs of :meth:`__call__`.

        Parameters
        ----------
        theta : array_like, shape (n_parameters,)
        p : ndarray
            The data vector.

        Returns
        -------
        ndarray, shape (N, n_outputs)
        """
        if self._output_loop is None:
            return self(theta, p)[0]
        N, nu = self.n_samples, len(self.model.inputs)
        theta, p = np.asarray(theta, dtype=float), np.asarray(p, dtype=float).reshape(-1)
        x0 = np.asarray(ca.densify(self._initial0(theta, p[N + (nu + self._nz) * N:]))).reshape(-1)
        _, (Y,) = self._output_loop(x0, self._rows(p), theta, keep_accumulators=False)
        return Y

    def _rows(self, p: np.ndarray) -> np.ndarray:
        """The loop's per-sample rows ``[u_k; u_a; u_b; dt]`` of the data vector (the last sample's
        interval empty), kept for the last record: a fit evaluates the same record at every step."""
        N, nu = self.n_samples, len(self.model.inputs)
        key, last = p.tobytes(), self._last_rows  # one read: another thread may replace it
        if last is not None and last[0] == key:
            return last[1]
        U = p[N:N + nu * N].reshape(N, nu)  # column-major (n_inputs x N): one sample's inputs together
        rows = np.zeros((N, self._loop.n_d))
        rows[:, :nu] = U
        if N > 1:
            n_step_u = (self._loop.n_d - nu - 1) // 2
            rows[:-1, nu:nu + n_step_u], rows[:-1, nu + n_step_u:-1] = self.model.interval_input_values(U)
            np.subtract(p[1:N], p[:N - 1], out=rows[:-1, -1])
        self._last_rows = (key, rows)
        return rows


_SENSITIVITIES = StructureCache()


def output_sensitivities(model: DynamicModel, n_samples: int, masked: bool = False, jit: bool = False,
                         jit_flags=("-O1",)) -> OutputSensitivities:
    """Cached :class:`OutputSensitivities` for (model, N, masked, jit)."""
    key = (n_samples, bool(masked), bool(jit), tuple(jit_flags))
    cache = _SENSITIVITIES.setdefault(model, {})
    if key not in cache:
        cache[key] = OutputSensitivities(model, n_samples, masked, jit, jit_flags)
    return cache[key]
