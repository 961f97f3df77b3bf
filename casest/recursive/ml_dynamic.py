"""The output-error predictor of recursive ML on a :class:`casest.DynamicModel`: the state simulated
with the current estimate and its parameter sensitivity propagated beside it (summary Sec. 5.2-5.3;
the recursive prediction-error method), one sample at a time."""

from __future__ import annotations

import casadi as ca
import numpy as np

from .._casadi.memory import StructureCache
from ..data.dataset import Dataset
from ..models import OptionError
from ..models.dynamic import DynamicModel

__all__ = ["OutputErrorPredictor"]

_RML_FUNCTIONS = StructureCache()


class OutputErrorPredictor:
    """x(k) and S(k) = dx(k)/dtheta of a dynamic model, advanced sample by sample.

    Parameters
    ----------
    model : DynamicModel
    x0 : array_like, shape (n_states,), optional
        The state at the first sample (its sensitivity zero); default: the model's initial
        state for the record, set by :meth:`start`.
    """

    def __init__(self, model: DynamicModel, x0=None):
        if model.output_delays:
            raise OptionError("recursive ML predicts each sample's own output: a model with output delays "
                              f"{list(model.output_delays.delays)} needs the whole record (use casest.estimate)")
        self.model = model
        self._step, self._measure, self._initial = _functions(model)
        self.x0 = None if x0 is None else np.asarray(x0, dtype=float).reshape(-1)
        self.x = self.S = self.last = None

    def start(self, data: Dataset, theta: np.ndarray) -> None:
        """Set x and S at the record's first sample (from ``x0``, or the model's initial state at ``theta``)."""
        n, p = self.model.n_states, self.model.n_parameters
        if self.x0 is not None:
            self.x, self.S = self.x0.copy(), np.zeros((n, p))
        else:
            x, S = self._initial(theta, self.model.initial_values(data))
            self.x, self.S = np.asarray(x).reshape(-1), np.asarray(S).reshape(n, p)
        self.last = None

    def advance(self, rows: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The predictions and their Jacobians at the given samples, moving x and S along.

        Parameters
        ----------
        rows : ndarray, shape (m, 1 + n_inputs)
            Time and inputs of the next samples, in time order.
        theta : ndarray, shape (n_parameters,)
            The estimate the predictions are made with.

        Returns
        -------
        h : ndarray, shape (m, n_outputs)
        J : ndarray, shape (m n_outputs, n_parameters)
            dh/dtheta through the state, rows sample-major.
        """
        if self.x is None:
            if self.x0 is None:
                raise OptionError("the dynamic model's state is not set: give x0 to RecursiveML or feed the "
                                  "record through RecursiveML.run(data)")
            self.x, self.S = self.x0.copy(), np.zeros((self.model.n_states, self.model.n_parameters))
        hs, Js = [], []
        for row in rows:
            if self.last is not None:
                self._propagate(self.last, row, theta)
            h, J = self._measure(self.x, self.S, row[1:], theta)
            hs.append(np.asarray(h).reshape(-1))
            Js.append(np.asarray(J))
            self.last = row
        return np.array(hs), np.vstack(Js)

    def _propagate(self, previous: np.ndarray, row: np.ndarray, theta: np.ndarray) -> None:
        dt = float(row[0] - previous[0])
        if not dt > 0:
            raise OptionError(f"recursive ML on a dynamic model needs samples in time order; t = {row[0]:g} follows "
                              f"t = {previous[0]:g}")
        Ua, Ub = self.model.interval_input_values(np.vstack([previous[1:], row[1:]]))
        x, S = self._step(self.x, self.S, Ua[0], Ub[0], dt, theta)
        self.x, self.S = np.asarray(x).reshape(-1), np.asarray(S)


def _functions(model: DynamicModel) -> tuple[ca.Function, ca.Function, ca.Function]:
    """The step with its sensitivity, the measurement with dh/dtheta through S, the initial state (cached)."""
    cache = _RML_FUNCTIONS.setdefault(model, {})
    if "step" not in cache:
        step = model.step_function
        Sym = ca.SX if step.is_a("SXFunction") else ca.MX
        n, p = model.n_states, model.n_parameters
        x, S, theta, dt = Sym.sym("x", n), Sym.sym("S", n, p), Sym.sym("theta", p), Sym.sym("dt")
        ua, ub = Sym.sym("u_a", step.size1_in(1)), Sym.sym("u_b", step.size1_in(2))
        th = ca.vertcat(*[theta[i] for i in model.rhs_parameter_index]) if model.rhs_parameter_index else Sym(0, 1)
        x_next = step(x, ua, ub, dt, th)
        S_next = ca.jacobian(x_next, x) @ S + ca.jacobian(x_next, theta)
        cache["step"] = ca.Function("rml_step", [x, S, ua, ub, dt, theta], [x_next, S_next])
        xs, Ss, us, ths = ca.SX.sym("x", n), ca.SX.sym("S", n, p), ca.SX.sym("u", len(model.inputs)), ca.SX.sym("t", p)
        h = model.output_model.function(ca.vertcat(xs, us), ths)
        cache["measure"] = ca.Function("rml_measure", [xs, Ss, us, ths],
                                       [h, ca.jacobian(h, xs) @ Ss + ca.jacobian(h, ths)])
        th0, d0 = ca.MX.sym("theta", p), ca.MX.sym("d0", len(model.initial_from_data))
        x0 = model.initial_function(th0, d0)
        cache["initial"] = ca.Function("rml_initial", [th0, d0], [x0, ca.jacobian(x0, th0)])
    return cache["step"], cache["measure"], cache["initial"]
