"""Flight-path reconstruction (data compatibility): the kinematics of a rigid body driven by
its measured rates (and, where logged, specific forces), with the sensors' biases as
parameters, checked against the measured attitude, velocity and position. It tells whether a
record's signals agree with each other before aerodynamic models are fitted to them, and
gives the rate (and accelerometer) biases to correct them with.

Kinematics (body rates p, q, r corrected as ``(1 + k) x_m - b``; Euler angles phi, theta,
psi; body velocity u, v, w; NED position x_N, x_E, x_D; g = 9.80665 m/s^2)::

    phi'   = p + (q sin phi + r cos phi) tan theta
    theta' = q cos phi - r sin phi
    psi'   = (q sin phi + r cos phi) / cos theta
    u' = a_x - g sin theta            + r v - q w          (with accelerations)
    v' = a_y + g cos theta sin phi    + p w - r u
    w' = a_z + g cos theta cos phi    + q u - p v
    x_NED' = C_b^n (u, v, w)  with accelerations,  or  V_NED,m - b_V  without

Outputs: the measured Euler angles (``phi_m``, ``theta_m``, ``psi_m``), with accelerations the
NED velocity (``V_N_m``, ``V_E_m``, ``V_D_m``), with ``position`` the NED position
(``x_N_m``, ``x_E_m``, ``x_D_m``). Every state starts from the record's first measured value
(``State(name, "data")``). :func:`flight_path_columns` builds the record's columns from the
measured arrays (the heading unwrapped, so that it does not jump by 2 pi).
"""

from __future__ import annotations

from typing import Mapping

import casadi as ca
import numpy as np

from ..errors import DataError
from .dynamic import DynamicModel, State
from .priors import Parameter, Signal
from ..options import InputHold

__all__ = ["flight_path_model", "flight_path_columns", "GRAVITY"]

GRAVITY = 9.80665  # m/s^2


def flight_path_model(*, accelerations: bool = False, position: bool = True, rate_scale: bool = False,
                      rate_bias_bound: float = 0.1, accel_bias_bound: float = 2.0,
                      velocity_bias_bound: float = 5.0, name: str = "flight_path",
                      input_hold: InputHold = "linear") -> DynamicModel:
    """The kinematic model of a record with measured rates, attitude and velocity (module docstring).

    Parameters
    ----------
    accelerations : bool
        The record has specific forces ``a_x, a_y, a_z`` (m/s^2): the body velocity is
        integrated from them (accelerometer biases estimated) and the NED velocity is an output.
        Without them the measured NED velocity drives the position (velocity biases estimated).
    position : bool
        Integrate the NED position and compare it with the measured one.
    rate_scale : bool
        Estimate a scale factor per rate gyro besides its bias.
    rate_bias_bound, accel_bias_bound, velocity_bias_bound : float
        The symmetric bounds of the biases (rad/s, m/s^2, m/s).
    name : str
    input_hold : {"linear", "cubic", "zoh"}
        How the measured signals are interpolated between samples while integrating.

    Returns
    -------
    DynamicModel
        Inputs ``p, q, r`` (rad/s), then ``a_x, a_y, a_z`` or ``V_N, V_E, V_D``; time ``t``.
    """
    s = {n: ca.SX.sym(n) for n in ("p", "q", "r", "phi", "theta", "psi")}
    parameters = [Parameter(f"b_{c}", -rate_bias_bound, rate_bias_bound, 0.0, unit="rad/s") for c in "pqr"]
    rates = []
    for c in "pqr":
        bias = ca.SX.sym(f"b_{c}")
        s[f"b_{c}"] = bias
        if rate_scale:
            k = s[f"k_{c}"] = ca.SX.sym(f"k_{c}")
            parameters.append(Parameter(f"k_{c}", -0.2, 0.2, 0.0))
            rates.append((1 + k) * s[c] - bias)
        else:
            rates.append(s[c] - bias)
    p, q, r = rates
    phi, theta, psi = s["phi"], s["theta"], s["psi"]
    rhs = {"phi": p + (q * ca.sin(phi) + r * ca.cos(phi)) * ca.tan(theta),
           "theta": q * ca.cos(phi) - r * ca.sin(phi),
           "psi": (q * ca.sin(phi) + r * ca.cos(phi)) / ca.cos(theta)}
    outputs = {"phi_m": phi, "theta_m": theta, "psi_m": psi}
    states = [State(n, "data", unit="rad") for n in ("phi", "theta", "psi")]
    inputs = [Signal(c, "rad/s") for c in "pqr"]
    units = {"phi_m": "rad", "theta_m": "rad", "psi_m": "rad"}
    if accelerations:
        velocity = _body_velocity(s, rates, parameters, rhs, states, inputs, accel_bias_bound)
        ground = ca.mtimes(_body_to_ned(phi, theta, psi), velocity)
        for axis, expr in zip("NED", ca.vertsplit(ground)):
            outputs[f"V_{axis}_m"] = expr
            units[f"V_{axis}_m"] = "m/s"
    elif position:
        ground = _measured_velocity(parameters, inputs, velocity_bias_bound)
    if position:
        for axis, expr in zip("NED", ca.vertsplit(ground)):
            rhs[f"x_{axis}"] = expr
            states.append(State(f"x_{axis}", "data", unit="m"))
            outputs[f"x_{axis}_m"] = ca.SX.sym(f"x_{axis}")
            units[f"x_{axis}_m"] = "m"
    return DynamicModel(parameters, states, inputs, rhs=rhs, outputs=outputs, name=name, output_units=units,
                        input_hold=input_hold)


def _body_velocity(s: dict, rates: list, parameters: list, rhs: dict, states: list, inputs: list,
                   bound: float):
    """Adds the body velocity driven by the specific forces (biases estimated); returns (u, v, w)."""
    p, q, r = rates
    u, v, w = (ca.SX.sym(n) for n in ("u", "v", "w"))
    force = []
    for axis in "xyz":
        bias = ca.SX.sym(f"b_a{axis}")
        parameters.append(Parameter(f"b_a{axis}", -bound, bound, 0.0, unit="m/s^2"))
        inputs.append(Signal(f"a_{axis}", "m/s^2"))
        force.append(ca.SX.sym(f"a_{axis}") - bias)
    phi, theta = s["phi"], s["theta"]
    rhs["u"] = force[0] - GRAVITY * ca.sin(theta) + r * v - q * w
    rhs["v"] = force[1] + GRAVITY * ca.cos(theta) * ca.sin(phi) + p * w - r * u
    rhs["w"] = force[2] + GRAVITY * ca.cos(theta) * ca.cos(phi) + q * u - p * v
    states += [State(n, "data", unit="m/s") for n in ("u", "v", "w")]
    return ca.vertcat(u, v, w)


def _measured_velocity(parameters: list, inputs: list, bound: float):
    """The measured NED velocity less its biases (inputs ``V_N, V_E, V_D``)."""
    out = []
    for axis in "NED":
        parameters.append(Parameter(f"b_V{axis}", -bound, bound, 0.0, unit="m/s"))
        inputs.append(Signal(f"V_{axis}", "m/s"))
        out.append(ca.SX.sym(f"V_{axis}") - ca.SX.sym(f"b_V{axis}"))
    return ca.vertcat(*out)


def _body_to_ned(phi, theta, psi):
    """C_b^n of the 3-2-1 Euler angles."""
    cf, sf, ct, st, cp, sp = ca.cos(phi), ca.sin(phi), ca.cos(theta), ca.sin(theta), ca.cos(psi), ca.sin(psi)
    return ca.vertcat(
        ca.horzcat(ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp),
        ca.horzcat(ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp),
        ca.horzcat(-st, sf * ct, cf * ct))


def flight_path_columns(model: DynamicModel, measured: Mapping[str, np.ndarray]) -> dict:
    """The columns of a record for a :func:`flight_path_model` from the measured arrays.

    Parameters
    ----------
    model : DynamicModel
        Made by :func:`flight_path_model`.
    measured : mapping of str to ndarray, shape (N,) each
        ``t`` (s), ``p, q, r`` (rad/s), ``phi, theta, psi`` (rad), and as the model needs
        ``a_x, a_y, a_z`` (m/s^2), ``u, v, w`` (m/s, body velocity: its first value starts
        the integration), ``V_N, V_E, V_D`` (m/s), ``x_N, x_E, x_D`` (m).

    Returns
    -------
    dict of str to ndarray
        Inputs, outputs and the states' starting columns; the heading unwrapped (no 2 pi jumps).

    Raises
    ------
    DataError
        A measured array the model needs is missing.
    """
    measured = {k: np.asarray(v, dtype=float).reshape(-1) for k, v in measured.items()}
    if "psi" in measured:
        measured["psi"] = np.unwrap(measured["psi"])
    wanted = {model.time} | {s.name for s in model.inputs} | set(model.state_names)
    wanted |= {o[:-2] for o in model.output_names}
    missing = sorted(n for n in wanted if n not in measured and not ("@" in n))
    if missing:
        raise DataError(f"the flight-path record needs {missing}; give them in the measured mapping")
    columns = {n: measured[n] for n in wanted if n in measured}
    columns.update({o: measured[o[:-2]] for o in model.output_names})
    return columns
