"""Dynamic models: states with an ODE, and outputs of the states (paper Appendix B.B, summary Sec. 5).

::

    dx/dt = f(x, u, theta),   x(t_0) = x_0(theta, data)
    z_k   = h(x(t_k), u_k, theta) + v_k

declared in the same style as :class:`casest.Model`: CasADi symbols matched by name to the
declared parameters, states and inputs. The sample times come from a time column of the
data (uniform or not). Between samples the inputs are interpolated linearly (default) or
held (``input_hold="zoh"``), or cubic (``"cubic"``, Catmull-Rom). The default discretisation is fixed-step RK4 with
``substeps`` steps per sample interval, built once as an SX step function and repeated
with CasADi's ``mapaccum``, so the expression graph does not grow with N;
``integrator="cvodes"`` uses CasADi's CVODES interface for each interval (stiff models).

Each state's initial value is fixed (a number), estimated (the name of a declared
parameter: that parameter is x_0) or taken from the data (``"data"``: the first value of
a data column named after the state, passed as an extra column; see :meth:`DynamicModel.dataset`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import casadi as ca
import numpy as np

from ..options import InputHold, Integrator, check_option, choices
from ..data.dataset import Dataset
from ..errors import ModelError
from .declarations import Declarations
from .delays import InputDelays, OutputDelays
from .dynamic_records import DynamicRecords
from .discretisation import Segments, build_step, interval_input_values, interval_inputs
from .priors import Parameter, Signal
from .static import Model
from .symbols import symbolic_expressions
from ..checks import whole_number


__all__ = ["State", "DynamicModel", "Segments", "INTEGRATORS", "INPUT_HOLDS"]  # Segments: its old home

INTEGRATORS = choices(Integrator)
INPUT_HOLDS = choices(InputHold)


@dataclass(frozen=True)
class State:
    """A state of a dynamic model.

    Parameters
    ----------
    name : str
        The CasADi symbol's name in the rhs and outputs.
    initial : float or str
        x(t_0): a number (fixed), the name of a declared parameter (estimated with the
        others), or ``"data"`` (the first value of the data column named ``name``).
    unit : str
    """

    name: str
    initial: float | str = 0.0
    unit: str = ""

    def __post_init__(self):
        if isinstance(self.initial, bool) or not isinstance(self.initial, (int, float, str, np.integer, np.floating)):
            raise ModelError(f"the initial value of state {self.name!r} must be a number, the name of a declared "
                             f"parameter or 'data', got {self.initial!r}")


class DynamicModel(Declarations, DynamicRecords):
    """A measurement model with states driven by an ODE.

    Parameters
    ----------
    parameters : sequence of Parameter
    states : sequence of State
    inputs : sequence of Signal or str
        Measured input signals u (the columns of the data besides the time).
    rhs : mapping of str to expression
        ``dx/dt`` of every state, in terms of parameters, states and inputs.
    outputs : mapping of str to expression
        The measured channels ``h(x, u, theta)``.
    time : str
        Name of the time column of the data (seconds), strictly increasing.
    name : str
    output_units : mapping of str to str, optional
    substeps : int
        RK4 steps per sample interval.
    integrator : {"rk4", "cvodes"}
    input_hold : {"linear", "cubic", "zoh"}
        Inputs between samples: linear interpolation; cubic (Catmull-Rom through the four
        nearest samples, in sample-index parametrisation, so meant for uniform sampling; the
        ends extrapolate linearly), whose interpolation error falls with dt^4 instead of dt^2
        (fast IMU signals integrated over long records); or held at the earlier sample.
    cvodes_tolerance : float
        Absolute and relative tolerance of CVODES.
    delays : mapping of str to str, optional
        Input name -> name of the parameter that is its time delay (s): the model sees
        ``u(t - tau)``, interpolated between samples, and ``tau`` is estimated with the
        others. Output name -> delay parameter (or a known delay in s): the output is the
        model's at ``t - tau``, interpolated between samples of the simulated outputs
        (output error by single shooting only). See :mod:`casest.models.delays` for the
        limits. Needs ``sample_time``.
    sample_time : float, optional
        The record's uniform sampling interval (s), for ``delays``.

    Attributes
    ----------
    output_model : Model
        ``h`` as a static model whose signals are the states, then the inputs.
    rhs_function : casadi.Function
        ``(x, u, theta) -> dx/dt``.
    initial_function : casadi.Function
        ``(theta, x0_data) -> x(t_0)``; ``x0_data`` holds the values of the states whose
        initial value comes from the data, in state order.
    dynamic_parameters : tuple of str
        Parameters in the rhs or the initial state: never linear (xi1).
    rhs_parameter_index : list of int
        Positions of the parameters the rhs depends on.
    step_function : casadi.Function
        ``(x, u_k, u_k+1, dt, theta_rhs) -> x_k+1``: one sample interval of the
        discretised ODE (``theta_rhs``: the parameters at ``rhs_parameter_index``).

    Examples
    --------
    A first-order lag with gain k and time constant tau, estimated by output error:

    >>> import casadi as ca
    >>> import numpy as np
    >>> import casest
    >>> x, u, k, tau = (ca.SX.sym(n) for n in ("x", "u", "k", "tau"))
    >>> model = casest.DynamicModel(
    ...     [casest.Parameter("k", 0.1, 10.0, 1.0), casest.Parameter("tau", 0.1, 10.0, 1.0)],
    ...     [casest.State("x", 0.0)], ["u"], rhs={"x": (k * u - x) / tau}, outputs={"y": x})
    >>> t = np.arange(400) * 0.05
    >>> u_in = np.sign(np.sin(0.8 * t))
    >>> _, y = model.simulate({"k": 2.0, "tau": 0.5}, model.dataset({"t": t, "u": u_in, "y": 0 * t}))
    >>> noise = 0.01 * np.random.default_rng(0).standard_normal(t.size)
    >>> est = casest.estimate(model, model.dataset({"t": t, "u": u_in, "y": y[:, 0] + noise}))
    >>> bool(np.all(np.abs(est.theta - [2.0, 0.5]) < 3 * est.std))   # the truth, within 3 std
    True

    """

    def __init__(
        self,
        parameters: Sequence[Parameter],
        states: Sequence[State],
        inputs: Sequence[Signal | str],
        rhs: Mapping[str, object],
        outputs: Mapping[str, object],
        *,
        time: str = "t",
        name: str = "dynamic_model",
        output_units: Mapping[str, str] | None = None,
        substeps: int = 1,
        integrator: Integrator = "rk4",
        input_hold: InputHold = "linear",
        cvodes_tolerance: float = 1e-10,
        segments: "Segments | None" = None,
        delays: Mapping[str, str] | None = None,
        sample_time: float | None = None,
    ):
        self._spec = dict(parameters=parameters, states=states, inputs=inputs, rhs=dict(rhs), outputs=dict(outputs),
                          time=time, name=name, output_units=output_units, substeps=substeps, integrator=integrator,
                          input_hold=input_hold, cvodes_tolerance=cvodes_tolerance, segments=segments,
                          delays=delays, sample_time=sample_time)
        self.name = str(name)
        output_delays = {k: v for k, v in dict(delays or {}).items() if k in outputs}
        self.input_delays = InputDelays({k: v for k, v in dict(delays or {}).items() if k not in outputs},
                                        sample_time, parameters, inputs)
        inputs = list(inputs) + self.input_delays.extra_inputs(inputs)
        rhs, outputs = self.input_delays.apply(rhs), self.input_delays.apply(outputs)
        self.states: tuple[State, ...] = tuple(s if isinstance(s, State) else State(str(s)) for s in states)
        self.inputs: tuple[Signal, ...] = tuple(Signal(s) if isinstance(s, str) else s for s in inputs)
        self.time = str(time)
        self.segments = segments
        self._check_options(integrator, input_hold, substeps)
        self.substeps, self.integrator, self.input_hold = int(substeps), integrator, input_hold
        self.cvodes_tolerance = float(cvodes_tolerance)
        signals = [Signal(s.name, s.unit) for s in self.states] + list(self.inputs)
        self.output_model = Model(parameters, signals, outputs, name=self.name, output_units=output_units,
                                  require_all_parameters=False)
        # composition: the output equation is a Model; its declarations are this model's
        self.parameters = self.output_model.parameters
        self.output_names, self.output_units = self.output_model.output_names, self.output_model.output_units
        pnames = list(self.output_model.parameter_names)
        self.output_delays = OutputDelays(output_delays, sample_time, self.parameters, self.output_names,
                                          segment_lengths=segments.lengths if segments is not None else ())
        if self.output_delays and segments is not None and not segments.lengths:
            raise ModelError("output delays mix neighbouring samples and must stop at the boundaries between "
                             "manoeuvres: stack the experiments with casest.problem.experiments.stack_dynamic_experiments "
                             "(casest.estimate(model, [record1, record2]) does), which records their lengths")
        theta, xdot = self._build_rhs(dict(rhs), pnames)
        self._build_initial(theta, pnames)
        self._classify_parameters(theta, xdot, pnames)
        self.step_function = build_step(self)
        self._cache: dict = {}

    def _classify_parameters(self, theta, xdot, pnames: list) -> None:
        """``dynamic_parameters`` and ``rhs_parameter_index``; refuse parameters that act nowhere."""
        resets = self.segments.parameters() if self.segments is not None else ()
        in_dynamics = [n for k, n in enumerate(pnames)
                       if ca.depends_on(xdot, theta[k]) or any(s.initial == n for s in self.states) or n in resets]
        self.dynamic_parameters: tuple[str, ...] = tuple(in_dynamics)
        # the step depends only on these (the rhs, and the experiments' initial states it restarts
        # from): the simulation takes them alone, so that derivatives with respect to the other
        # parameters never pass through the time recursion
        self.rhs_parameter_index = [k for k, n in enumerate(pnames) if ca.depends_on(xdot, theta[k]) or n in resets]
        h_params = {n for k, n in enumerate(pnames) if ca.depends_on(self.output_model.h, self.output_model.theta[k])}
        h_params |= set(self.output_delays.parameter_names)
        unused = [n for n in pnames if n not in h_params and n not in in_dynamics]
        if unused:
            raise ModelError(f"parameter(s) {unused} appear in no output, no rhs and no initial state, so the data "
                             "cannot determine them; remove them or use them")

    def _check_options(self, integrator: str, input_hold: str, substeps) -> None:
        """Refuse unknown integrators and holds, a bad substep count and names used twice."""
        if not self.states:
            raise ModelError("a DynamicModel needs at least one State")
        check_option("integrator", integrator, Integrator)
        check_option("input_hold", input_hold, InputHold)
        substeps = whole_number(substeps, "substeps must be a positive integer")
        state_names = [s.name for s in self.states]
        input_names = [s.name for s in self.inputs]
        clash = sorted(set(state_names) & set(input_names)) + ([self.time] if self.time in state_names + input_names else [])
        if clash:
            raise ModelError(f"names {clash} are used twice among states, inputs and the time column")

    def _build_rhs(self, rhs: dict, pnames: list) -> tuple:
        """``rhs_function`` from the user's expressions; returns the parameter symbols and dx/dt."""
        state_names, input_names = list(self.state_names), [s.name for s in self.inputs]
        missing = [n for n in state_names if n not in rhs]
        unknown = [n for n in rhs if n not in state_names]
        if missing or unknown:
            raise ModelError("rhs needs one expression per state " + str(state_names)
                             + (f"; missing: {missing}" if missing else "") + (f"; not states: {unknown}" if unknown else ""))
        exprs, symbols = symbolic_expressions([rhs[n] for n in state_names], pnames + state_names + input_names)
        for n, e in zip(state_names, exprs):
            if e.numel() != 1:
                raise ModelError(f"the rhs of state {n!r} must be scalar, got shape {e.shape}")
        x = ca.vertcat(*[symbols[n] for n in state_names])
        u = ca.vertcat(*[symbols[n] for n in input_names]) if input_names else ca.SX(0, 1)
        theta = ca.vertcat(*[symbols[n] for n in pnames]) if pnames else ca.SX(0, 1)
        xdot = ca.vertcat(*exprs)
        self.rhs_function = ca.Function("f", [x, u, theta], [xdot], ["x", "u", "theta"], ["xdot"])
        return theta, xdot

    def _build_initial(self, theta, pnames: list) -> None:
        """``initial_function``: each state's x(t_0), a constant, a parameter or a value from the data."""
        from_data = [s.name for s in self.states if isinstance(s.initial, str) and s.initial == "data"]
        d0 = ca.SX.sym("x0_data", len(from_data))
        x0 = []
        for s in self.states:
            if isinstance(s.initial, str):
                if s.initial == "data":
                    x0.append(d0[from_data.index(s.name)])
                elif s.initial in pnames:
                    x0.append(theta[pnames.index(s.initial)])
                else:
                    raise ModelError(f"the initial value of state {s.name!r} is {s.initial!r}: give a number, the name "
                                     f"of a declared parameter {pnames}, or 'data'")
            else:
                value = float(s.initial)
                if not math.isfinite(value):
                    raise ModelError(f"the initial value of state {s.name!r} must be finite, got {value}")
                x0.append(ca.SX(value))
        self.initial_from_data: tuple[str, ...] = tuple(from_data)
        self.initial_function = ca.Function("x0", [theta, d0], [ca.vertcat(*x0)], ["theta", "x0_data"], ["x0"])

    # ------------------------------------------------------------------ declarations (the rest: Declarations)

    @property
    def state_names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.states)

    @property
    def n_states(self) -> int:
        return len(self.states)

    @property
    def signals(self) -> tuple[Signal, ...]:
        """The data's signal columns: the time, then the inputs."""
        return (Signal(self.time, "s"),) + self.inputs

    @property
    def structure_key(self) -> str:
        """A hash of the states, rhs, outputs and discretisation (see :attr:`Model.structure_key`)."""
        if getattr(self, "_structure_key", None) is None:
            import hashlib

            text = "\0".join([self.output_model.structure_key, self.rhs_function.serialize(),
                               self.initial_function.serialize(), repr(self.states), repr(self.inputs), self.time,
                               repr((self.substeps, self.integrator, self.input_hold, self.cvodes_tolerance)),
                               repr(self.output_delays)])
            self._structure_key = hashlib.sha256(text.encode()).hexdigest()
        return self._structure_key

    def __repr__(self) -> str:
        return (f"DynamicModel({self.name!r}, parameters={list(self.parameter_names)}, states={list(self.state_names)}, "
                f"inputs={[s.name for s in self.inputs]}, outputs={list(self.output_names)})")

    # ------------------------------------------------------------------ data
    def interval_inputs(self, U):
        """The step function's input arguments for every interval (:func:`casest.models.discretisation.interval_inputs`).

        Parameters
        ----------
        U : casadi.MX, shape (n_inputs, N)

        Returns
        -------
        Ua, Ub : casadi.MX, shape (n_step_inputs, N-1) each
        """
        return interval_inputs(self, U)

    def interval_input_values(self, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Numeric :meth:`interval_inputs`, shapes (N-1, n) each (:func:`casest.models.discretisation.interval_input_values`).

        Parameters
        ----------
        U : ndarray, shape (N, n_inputs)

        Returns
        -------
        Ua, Ub : ndarray, shape (N-1, n_step_inputs) each
        """
        return interval_input_values(self, U)

    def trajectory_symbols(self, theta: ca.MX, x0_data: ca.MX, T: ca.MX, U: ca.MX) -> ca.MX:
        """The states at every sample as a CasADi expression, shape (n_states, N).

        Parameters
        ----------
        theta : casadi.MX, shape (n_parameters, 1)
        x0_data : casadi.MX, shape (len(initial_from_data), 1)
        T : casadi.MX, shape (1, N)
            Sample times.
        U : casadi.MX, shape (n_inputs, N)

        Returns
        -------
        casadi.MX, shape (n_states, N)
        """
        N = T.size2()
        x0 = self.initial_function(theta, x0_data)
        if N == 1:
            return x0
        T0, T1 = ca.horzsplit(T, [0, N - 1, N])[0], ca.horzsplit(T, [0, 1, N])[1]
        Ua, Ub = self.interval_inputs(U)
        run = self.step_function.mapaccum("simulate", N - 1)
        theta_rhs = ca.vertcat(*[theta[i] for i in self.rhs_parameter_index]) if self.rhs_parameter_index else ca.MX(0, 1)
        X = run(x0, Ua, Ub, T1 - T0, ca.repmat(theta_rhs, 1, N - 1))
        return ca.horzcat(x0, X)

    def _functions(self, N: int, jacobian: bool = False) -> dict:
        """Simulation and output Functions for N samples (cached); with ``jacobian`` also the outputs'
        Jacobian through the simulation (built on first use: CasADi's AD of a long record takes seconds)."""
        if N not in self._cache:
            n, nu = self.n_parameters, len(self.inputs)
            theta, d0 = ca.MX.sym("theta", n), ca.MX.sym("x0_data", len(self.initial_from_data))
            T, U = ca.MX.sym("t", 1, N), ca.MX.sym("u", nu, N)
            X = self.trajectory_symbols(theta, d0, T, U)
            Y = self.output_sequences(X, U, theta)
            inputs, names = [theta, d0, T, U], ["theta", "x0_data", "t", "u"]
            self._cache[N] = {
                "states": ca.Function("states", inputs, [X], names, ["x"]),
                "outputs": ca.Function("outputs", inputs, [Y, X], names, ["z", "x"]),
                "symbols": (inputs, names, Y, theta),
            }
        functions = self._cache[N]
        if jacobian and "jacobian" not in functions:
            inputs, names, Y, theta = functions["symbols"]
            functions["jacobian"] = ca.Function("outputs_jacobian", inputs, [Y, ca.jacobian(ca.vec(Y), theta)], names,
                                                 ["z", "J"])
        return functions

    def output_sequences(self, X, U, theta):
        """The outputs at every sample as a CasADi expression, shape (n_outputs, N): the output equation
        mapped over the states X (n_states x N) and inputs U (n_inputs x N), delayed outputs delayed.

        Parameters
        ----------
        X : casadi.MX, shape (n_states, N)
        U : casadi.MX, shape (n_inputs, N)
        theta : casadi.MX, shape (n_parameters, 1)

        Returns
        -------
        casadi.MX, shape (n_outputs, N)
        """
        return self.delayed_outputs(self.output_model.function.map(X.size2())(ca.vertcat(X, U), theta), theta)

    def delayed_outputs(self, Y, theta):
        """The output sequences ``Y`` (n_outputs x N, CasADi) with the delayed outputs delayed
        (:class:`casest.models.delays.OutputDelays`); ``Y`` itself when no output is delayed.

        Parameters
        ----------
        Y : casadi.MX, shape (n_outputs, N)
        theta : casadi.MX, shape (n_parameters, 1)

        Returns
        -------
        casadi.MX, shape (n_outputs, N)
        """
        return self.output_delays.apply(Y, theta, self.parameter_names) if self.output_delays else Y

    def _arguments(self, theta, data: Dataset) -> list:
        self.check_data(data)
        return [self.vector(theta), self.initial_values(data), data.signals[:, 0][None, :], data.signals[:, 1:].T]

    def simulate(self, theta, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        """States and noise-free outputs at the data's samples.

        Parameters
        ----------
        theta : array_like, shape (n_parameters,), or mapping
        data : Dataset
            Times, inputs and (for ``initial="data"`` states) initial values.

        Returns
        -------
        states : ndarray, shape (N, n_states)
        outputs : ndarray, shape (N, n_outputs)
        """
        Y, X = self._functions(data.n_samples)["outputs"](*self._arguments(theta, data))
        return np.asarray(X).T, np.asarray(Y).T

    def predict_data(self, theta, data: Dataset) -> np.ndarray:
        """Noise-free outputs at the data's samples, shape (N, n_outputs).

        Parameters
        ----------
        theta : mapping or array_like, shape (n_parameters,)
        data : Dataset

        Returns
        -------
        ndarray, shape (N, n_outputs)
        """
        return self.simulate(theta, data)[1]

    def prediction_and_jacobian(self, data: Dataset, theta) -> tuple[np.ndarray, np.ndarray]:
        """h and d h / d theta (through the states) at every sample, sample-major.

        Returns
        -------
        h : ndarray, shape (N * n_outputs,)
        J : ndarray, shape (N * n_outputs, n_parameters)

        Parameters
        ----------
        data : Dataset
        theta : array_like, shape (n_parameters,)
        """
        Y, J = self._functions(data.n_samples, jacobian=True)["jacobian"](*self._arguments(theta, data))
        return np.asarray(Y).T.reshape(-1), np.asarray(J)

    def with_output_weights(self, weights) -> "DynamicModel":
        """The model with each output multiplied by a weight (known-noise weighting), shape (n_outputs,).

        Parameters
        ----------
        weights : array_like, shape (n_outputs,)

        Returns
        -------
        DynamicModel
        """
        weights = np.asarray(weights, dtype=float).reshape(-1)
        h = self.output_model.h
        spec = dict(self._spec)
        # the output model's own symbols stand for the same names as the user's
        spec["outputs"] = {n: float(w) * h[j] for j, (n, w) in enumerate(zip(self.output_names, weights))}
        return DynamicModel(**{k: v for k, v in spec.items() if k not in ("parameters", "states", "inputs", "rhs",
                                                                              "outputs")},
                            parameters=spec["parameters"], states=spec["states"], inputs=spec["inputs"],
                            rhs=spec["rhs"], outputs=spec["outputs"])

    def with_fixed(self, values: Mapping[str, float]) -> "DynamicModel":
        """The model with some parameters held at given values, substituted into the rhs, the
        outputs and the initial states.

        Parameters
        ----------
        values : mapping of str to float
            Parameter name -> value (physical unit), each inside the parameter's bounds.

        Returns
        -------
        DynamicModel
            The other parameters in the same order; states, inputs, outputs and the
            discretisation as before (a state whose initial value was a fixed parameter
            starts at its value).

        Raises
        ------
        ModelError
            An unknown name, a non-finite value or one outside the bounds, or every
            parameter fixed.
        """
        values = {str(k): float(v) for k, v in dict(values).items()}
        reduced_outputs = self.output_model.with_fixed(values)  # checks names, values and bounds
        kept = reduced_outputs.parameters
        symbols = {n: ca.SX.sym(n) for n in [p.name for p in kept] + list(self.state_names)
                   + [u.name for u in self.inputs]}
        theta = ca.vertcat(*[ca.SX(values[n]) if n in values else symbols[n] for n in self.parameter_names])
        x = ca.vertcat(*[symbols[n] for n in self.state_names])
        u = ca.vertcat(*[symbols[v.name] for v in self.inputs]) if self.inputs else ca.SX(0, 1)
        xdot = self.rhs_function(x, u, theta)
        h = self.output_model.function(ca.vertcat(x, u), theta)
        states = [State(s.name, values.get(s.initial, s.initial) if isinstance(s.initial, str) else s.initial, s.unit)
                  for s in self.states]
        spec = {k: v for k, v in self._spec.items() if k not in ("parameters", "states", "rhs", "outputs")}
        if spec.get("delays"):  # a fixed output delay becomes a known one
            spec["delays"] = {k: (values[v] if k in self.output_names and isinstance(v, str) and v in values else v)
                              for k, v in spec["delays"].items()}
        if self.segments is not None:
            spec["segments"] = self.segments.with_values(values)
        return DynamicModel(kept, states, rhs={n: xdot[i] for i, n in enumerate(self.state_names)},
                            outputs={n: h[j] for j, n in enumerate(self.output_names)}, **spec)
