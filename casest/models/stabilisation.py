"""Artificial stabilisation of an unstable model for output error (flight-test practice: Jategaonkar,
*Flight Vehicle System Identification*, Sec. 9.15, beside multiple shooting).

Output error integrates the model over the whole record; on an open-loop unstable aircraft any
parameter error grows exponentially and the fit stalls. Artificial stabilisation feeds the
measured outputs back into the simulation through a fixed gain chosen by the user::

    dx/dt = f(x, u, theta) + K_s (z - h(x, u, theta))

so that ``A - K_s C`` is stable and the simulated states stay near the measured ones. The
measured outputs become inputs of the stabilised model (columns ``fed_back_<output>``); output
error then fits it as any dynamic model. The gain is not estimated: it should be as small as
keeps the simulation bounded, since the fed-back measurement noise enters the states (a larger
gain biases the estimates towards the equation-error solution). Multiple shooting
(``SolverSettings(shooting="multiple")``) is the alternative that needs no gain.
"""

from __future__ import annotations

import warnings

import casadi as ca
import numpy as np

from ..data.dataset import Dataset
from ..errors import ModelError, OptionError
from .dynamic import DynamicModel
from .priors import Signal

__all__ = ["artificially_stabilised", "stabilised_dataset", "fed_back_name"]


def fed_back_name(output: str) -> str:
    """The input column that carries a measured output into the stabilised model."""
    return f"fed_back_{output}"


def artificially_stabilised(model: DynamicModel, gain) -> DynamicModel:
    """The model with its measured outputs fed back into the rhs through ``gain``.

    Parameters
    ----------
    model : DynamicModel
        Without output delays or stacked experiments.
    gain : array_like, shape (n_states, n_outputs)
        ``K_s`` in state-rate units per output unit; outputs whose column is zero are not fed back.

    Returns
    -------
    DynamicModel
        Named ``<name>_stabilised``, with the inputs of ``model`` followed by one input
        ``fed_back_<output>`` per fed-back output; the same parameters, states and outputs.

    Raises
    ------
    ModelError
        When the gain's shape does not match the model, it is not finite or all zero, or the
        model delays outputs or stacks experiments.
    OptionError
        Not a DynamicModel.

    Warns
    -----
    RuntimeWarning
        When ``A - K C``, linearised at the nominal parameters with states and inputs zero, has
        an eigenvalue of positive real part: the gain does not stabilise there (a gain of the
        wrong sign destabilises, and the estimate then ends on its bounds for no stated reason).
    """
    if not isinstance(model, DynamicModel):
        raise OptionError(f"artificially_stabilised takes a casest.DynamicModel (states to stabilise), got "
                          f"{type(model).__name__}")
    K = np.asarray(gain, dtype=float)
    shape = (model.n_states, model.n_outputs)
    if K.shape != shape:
        raise ModelError(f"the stabilising gain must have shape (n_states, n_outputs) = {shape} (rows "
                         f"{list(model.state_names)}, columns {list(model.output_names)}), got {K.shape}")
    if not np.all(np.isfinite(K)) or not np.any(K):
        raise ModelError("the stabilising gain must be finite and not all zero: give the feedback of the measured "
                         "outputs that makes A - K C stable")
    if model.output_delays or model.segments is not None:
        raise ModelError("artificial stabilisation takes a model without output delays or stacked experiments: "
                         "stabilise each experiment's model, or use multiple shooting")
    spec = dict(model._spec)
    outputs = spec["outputs"]
    fed = [j for j in range(model.n_outputs) if np.any(K[:, j])]
    measured = {j: ca.SX.sym(fed_back_name(model.output_names[j])) for j in fed}
    rhs = {}
    for i, state in enumerate(model.state_names):
        feedback = sum((K[i, j] * (measured[j] - outputs[model.output_names[j]]) for j in fed if K[i, j]), ca.SX(0))
        rhs[state] = ca.SX(spec["rhs"][state]) + feedback
    units = dict(zip(model.output_names, model.output_units))
    inputs = list(spec["inputs"]) + [Signal(fed_back_name(model.output_names[j]), units.get(model.output_names[j], ""))
                                     for j in fed]
    spec.update(rhs=rhs, inputs=inputs, name=f"{model.name}_stabilised")
    _warn_if_not_stabilising(model, K)
    return DynamicModel(**spec)


def _warn_if_not_stabilising(model: DynamicModel, K: np.ndarray) -> None:
    """Warn when ``A - K C`` at the nominal parameters (states and inputs zero) is not stable."""
    x = ca.SX.sym("x", model.n_states)
    u = ca.SX.sym("u", len(model.inputs))
    theta = ca.SX.sym("theta", model.n_parameters)
    z = ca.vertcat(x, u)
    f = ca.Function("AC", [x, u, theta], [ca.jacobian(model.rhs_function(x, u, theta), x),
                                           ca.jacobian(model.output_model.function(z, theta), x)])
    try:
        A, C = (np.asarray(M, dtype=float) for M in f(np.zeros(model.n_states), np.zeros(len(model.inputs)),
                                                      np.asarray(model.nominal, dtype=float)))
        closed = np.linalg.eigvals(A - K @ C)
    except (RuntimeError, np.linalg.LinAlgError):
        return  # no linearisation at that point: nothing to say
    worst = float(np.max(closed.real)) if closed.size else -np.inf
    if np.isfinite(worst) and worst > 0:
        warnings.warn(f"the stabilising gain leaves A - K C unstable at the nominal parameters (an eigenvalue with "
                      f"real part {worst:.4g} > 0; A's own largest is {float(np.max(np.linalg.eigvals(A).real)):.4g}): "
                      "output error will diverge as without it; choose K so that A - K C is stable (a gain of the "
                      "wrong sign destabilises)", RuntimeWarning, stacklevel=3)


def stabilised_dataset(stabilised: DynamicModel, data: Dataset) -> Dataset:
    """The record for the stabilised model: ``data``'s columns plus each fed-back output as an input.

    Parameters
    ----------
    stabilised : DynamicModel
        From :func:`artificially_stabilised`.
    data : Dataset
        The original model's record (complete outputs: a fed-back channel cannot be missing).

    Returns
    -------
    Dataset

    Raises
    ------
    OptionError
        Not a stabilised DynamicModel and a Dataset.
    ModelError
        A fed-back output with missing samples.
    """
    if not isinstance(stabilised, DynamicModel) or not isinstance(data, Dataset):
        raise OptionError(f"stabilised_dataset takes the stabilised casest.DynamicModel and the original model's "
                          f"casest.Dataset, got {type(stabilised).__name__} and {type(data).__name__}")
    columns = {name: data.column(name) for name in data.signal_names + data.output_names}
    columns.update(data.extra)
    prefix = fed_back_name("")
    for signal in stabilised.inputs:
        if signal.name.startswith(prefix) and signal.name not in columns:
            values = data.column(signal.name[len(prefix):])
            if not np.all(np.isfinite(values)):
                raise ModelError(f"the fed-back output {signal.name[len(prefix):]!r} has missing samples: a "
                                 "stabilised simulation needs it at every sample; fill or cut them")
            columns[signal.name] = values
    return stabilised.dataset(columns)
