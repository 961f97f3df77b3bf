"""Rate responses of the Ampyx Power AP2 on its real flight record: roll, pitch and yaw rate
from the control-surface deflections, by output error with an estimated input delay.

Linear rate dynamics with the aerodynamic terms scaled by the dynamic pressure, from the
measured airspeed as n = (V / 25 m/s)^2 (the record's mean airspeed is 24.7 m/s), the flow
angles as inputs, and the tether tension T (kN) in the pitching moment, where the tether
pulls below the centre of gravity::

    p' = n (L_0 + L_beta beta + L_da da + L_dr dr) + L_p p + L_r r
    q' = n (M_0 + M_alpha alpha + M_de de) + M_q q + M_T T
    r' = n (N_0 + N_beta beta + N_dr dr + N_da da) + N_p p + N_r r

The three deflections reach the surfaces delayed by one estimated ``tau`` (actuator lag and
logging offset). Each state starts at the segment's first measured rate. The record
(``data/ampyx_ap2``: Ampyx Power AP2 flight data, courtesy of Ampyx Power B.V. and the TU
Delft Airborne Wind Energy group, Apache License 2.0) is cut into three segments of about 16 s;
two are estimated together and the third validates (``python3 scripts/examples/ampyx_example.py``).
"""

from __future__ import annotations

import casadi as ca

import casest

RECORD = ("ampyx_ap2", "validationDataFC114_1_v2_pc.mat")
V_REF = 25.0  # m/s, the airspeed at which n = 1
SAMPLE_TIME = 0.02  # s, the record's mean interval (its stamps stray by 0.13 ms at most)

VARIABLES = {
    "t": "validationData.controls.times",
    "da": "validationData.controls.aileron",
    "de": "validationData.controls.elevator",
    "dr": "validationData.controls.rudder",
    "V": "validationData.response.airspeed",
    "alpha": "validationData.response.angleOfAttack",
    "beta": "validationData.response.sideSlip",
    "T": "validationData.response.tetherTension",
    "p": "validationData.response.w[0]",
    "q": "validationData.response.w[1]",
    "r": "validationData.response.w[2]",
    "p_m": "validationData.response.w[0]",
    "q_m": "validationData.response.w[1]",
    "r_m": "validationData.response.w[2]",
}

#: Estimation segments and the held-out one (s from the start of the record).
SEGMENTS = {"s1": (0.0, 16.4), "s2": (16.4, 32.8)}
VALIDATION = {"s3": (32.8, 49.4)}

#: Stage 1 sweeps the delay and the damping and cross terms; the control and static terms are linear.
SWEEP_SETTINGS = casest.SweepSettings(design="sobol", n_candidates=1024)


def model(delay: str | None = "input") -> casest.DynamicModel:
    """The rate-response model of the module docstring.

    Parameters
    ----------
    delay : {"input", "output", None}
        Where ``tau`` acts: on the three deflections (default), on the three measured rates
        (an output delay: the sensors' lag), or nowhere (no ``tau``).

    Returns
    -------
    DynamicModel
    """
    names = ["p", "q", "r", "da", "de", "dr", "V", "alpha", "beta", "T"]
    s = {n: ca.SX.sym(n) for n in names}
    P = casest.Parameter
    coefficients = {
        "L_0": (-5, 5), "L_beta": (-50, 50), "L_da": (-100, 100), "L_dr": (-100, 100), "L_p": (-60, 0),
        "L_r": (-20, 20),
        "M_0": (-10, 10), "M_alpha": (-100, 100), "M_de": (-100, 100), "M_q": (-60, 0), "M_T": (-5, 5),
        "N_0": (-5, 5), "N_beta": (-50, 50), "N_dr": (-100, 100), "N_da": (-100, 100), "N_p": (-20, 20),
        "N_r": (-60, 0), "M_pr": (-5, 5),
    }
    c = {n: ca.SX.sym(n) for n in coefficients}
    speed = s["V"] / V_REF
    n = speed**2
    tension = s["T"] / 1000.0
    rhs = {
        "p": n * (c["L_0"] + c["L_beta"] * s["beta"] + c["L_da"] * s["da"] + c["L_dr"] * s["dr"])
        + speed * (c["L_p"] * s["p"] + c["L_r"] * s["r"]),
        "q": n * (c["M_0"] + c["M_alpha"] * s["alpha"] + c["M_de"] * s["de"]) + speed * c["M_q"] * s["q"]
        + c["M_T"] * tension + c["M_pr"] * s["p"] * s["r"],
        "r": n * (c["N_0"] + c["N_beta"] * s["beta"] + c["N_dr"] * s["dr"] + c["N_da"] * s["da"])
        + speed * (c["N_p"] * s["p"] + c["N_r"] * s["r"]),
    }
    parameters = [P(name, lo, hi, 0.0 if lo < 0 < hi else (lo + hi) / 2) for name, (lo, hi) in coefficients.items()]
    if delay is not None:
        parameters.append(P("tau", 0.0, 0.2, 0.04, unit="s"))
    delays = ({"da": "tau", "de": "tau", "dr": "tau"} if delay == "input"
              else {"p_m": "tau", "q_m": "tau", "r_m": "tau"} if delay == "output" else None)
    inputs = [casest.Signal("da", "rad"), casest.Signal("de", "rad"), casest.Signal("dr", "rad"),
              casest.Signal("V", "m/s"), casest.Signal("alpha", "rad"), casest.Signal("beta", "rad"),
              casest.Signal("T", "N")]
    return casest.DynamicModel(
        parameters, [casest.State(k, "data", unit="rad/s") for k in ("p", "q", "r")], inputs, rhs=rhs,
        outputs={"p_m": s["p"], "q_m": s["q"], "r_m": s["r"]}, name="ampyx_rates",
        output_units={"p_m": "rad/s", "q_m": "rad/s", "r_m": "rad/s"},
        delays=delays, sample_time=SAMPLE_TIME)


def load(window: tuple[float, float] | None = None, delay: str | None = "input") -> casest.Dataset:
    """The bundled record as published (struct paths), optionally one time window (s).

    Parameters
    ----------
    window : (float, float), optional
    delay : {"input", "output", None}
        The :func:`model` variant the record is read for.

    Returns
    -------
    Dataset
    """
    data = casest.Dataset.from_mat(model(delay), casest.bundled_data_dir(*RECORD), variables=VARIABLES)
    if window is None:
        return data
    t = data.column("t")
    return data.subset((t >= window[0]) & (t < window[1]))


def segments(windows: dict | None = None, delay: str | None = "input") -> dict:
    """The estimation segments by name (default :data:`SEGMENTS`).

    Parameters
    ----------
    windows : dict of str to (float, float), optional
    delay : {"input", "output", None}
        The :func:`model` variant the records are read for.

    Returns
    -------
    dict of str to Dataset
    """
    return {name: load(window, delay) for name, window in (windows or SEGMENTS).items()}


def main() -> casest.Estimate:
    """Estimate on the two segments, validate on the third, print both."""
    est = casest.estimate(model(), segments(), sweep_settings=SWEEP_SETTINGS)
    print(est.report())
    print(est.validate(model(), load(VALIDATION["s3"])).report())
    return est


if __name__ == "__main__":
    main()
