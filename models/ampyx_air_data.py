"""Air-data calibration of the Ampyx Power AP2 on its real flight record (paper Sec. IV form).

The air-data system measures the airspeed V_m and the flow angles alpha_m, beta_m; the
navigation solution gives the ground velocity V_NED and the attitude (the rotation matrix
C_b^n, body to NED). The error model has the paper's shape (Eq. 36-41)::

    V_a   = (1 + lambda_V) V_m + b_V
    alpha = (1 + lambda_alpha) alpha_m + b_alpha
    beta  = (1 + lambda_beta)  beta_m  + b_beta
    V_NED = C_b^n C(eps_a)^T V_a (cos alpha cos beta, sin beta, sin alpha cos beta) + W

with a vane misalignment eps_a about the body x axis and a constant wind W over the record.
The separator finds xi1 = [lambda_V b_V W_N W_E W_D] (they enter jointly affinely) and xi2 =
[lambda_alpha b_alpha lambda_beta b_beta eps_a], the paper's Eq. 42. The lever arm of the
probe is not known for this aircraft and is left out (body rates of 0.15-0.26 rad/s rms give
about 0.2 m/s per metre of arm).

Data: the bundled record ``data/ampyx_ap2`` (Ampyx Power AP2 flight data, courtesy of Ampyx
Power B.V. and the TU Delft Airborne Wind Energy group, Apache License 2.0). Run
``python3 models/ampyx_air_data.py`` for the estimate, ``python3 scripts/examples/ampyx_example.py``
for the whole worked example.
"""

from __future__ import annotations

import casadi as ca

import casest

RECORD = ("ampyx_ap2", "validationDataFC114_1_v2_pc.mat")

#: Where each column is in the published file (struct paths, channel indices from 0).
VARIABLES = {
    "t": "validationData.controls.times",
    "V_m": "validationData.response.airspeed",
    "alpha_m": "validationData.response.angleOfAttack",
    "beta_m": "validationData.response.sideSlip",
    **{f"C{i}{j}": f"validationData.response.R[{i}, {j}]" for i in range(3) for j in range(3)},
    "V_N": "validationData.response.v[0]",
    "V_E": "validationData.response.v[1]",
    "V_D": "validationData.response.v[2]",
}

SIGNALS = [("V_m", "m/s"), ("alpha_m", "rad"), ("beta_m", "rad")] + [(f"C{i}{j}", "") for i in range(3)
                                                                      for j in range(3)]

#: Stage 1: 2000 scrambled Sobol candidates of xi2 in its box.
SWEEP_SETTINGS = casest.SweepSettings(design="sobol", n_candidates=2048)


def model() -> casest.Model:
    """The wind triangle with the air-data error model (module docstring)."""
    names = [n for n, _ in SIGNALS] + ["lambda_V", "b_V", "lambda_alpha", "b_alpha", "lambda_beta", "b_beta",
                                       "eps_a", "W_N", "W_E", "W_D"]
    s = {n: ca.SX.sym(n) for n in names}
    va = (1 + s["lambda_V"]) * s["V_m"] + s["b_V"]
    alpha = (1 + s["lambda_alpha"]) * s["alpha_m"] + s["b_alpha"]
    beta = (1 + s["lambda_beta"]) * s["beta_m"] + s["b_beta"]
    direction = ca.vertcat(ca.cos(alpha) * ca.cos(beta), ca.sin(beta), ca.sin(alpha) * ca.cos(beta))
    ce, se = ca.cos(s["eps_a"]), ca.sin(s["eps_a"])
    misalignment = ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, ce, -se), ca.horzcat(0, se, ce))
    C_bn = ca.vertcat(*[ca.horzcat(*[s[f"C{i}{j}"] for j in range(3)]) for i in range(3)])
    wind = ca.vertcat(s["W_N"], s["W_E"], s["W_D"])
    v_ned = ca.mtimes(C_bn, ca.mtimes(misalignment, direction)) * va + wind
    P = casest.Parameter
    parameters = [
        P("lambda_V", -0.3, 0.3, 0.0),
        P("b_V", -5.0, 5.0, 0.0, unit="m/s"),
        P("lambda_alpha", -0.8, 0.8, 0.0),
        P("b_alpha", -0.3, 0.3, 0.0, unit="rad"),
        P("lambda_beta", -0.5, 0.5, 0.0),
        P("b_beta", -0.3, 0.3, 0.0, unit="rad"),
        P("eps_a", -0.5, 0.5, 0.0, unit="rad"),
        P("W_N", -20.0, 20.0, 0.0, unit="m/s"),
        P("W_E", -20.0, 20.0, 0.0, unit="m/s"),
        P("W_D", -5.0, 5.0, 0.0, unit="m/s"),
    ]
    return casest.Model(parameters=parameters, signals=[casest.Signal(n, u) for n, u in SIGNALS],
                        outputs={"V_N": v_ned[0], "V_E": v_ned[1], "V_D": v_ned[2]}, name="ampyx_air_data",
                        output_units={"V_N": "m/s", "V_E": "m/s", "V_D": "m/s"})


def load(window: tuple[float, float] | None = None) -> casest.Dataset:
    """The bundled AP2 record as published, read by struct paths (time kept in ``extra["t"]``).

    Parameters
    ----------
    window : (float, float), optional
        Keep the samples with ``t0 <= t < t1`` (s from the start of the record).

    Returns
    -------
    Dataset
    """
    data = casest.Dataset.from_mat(model(), casest.bundled_data_dir(*RECORD), variables=VARIABLES, extra=["t"],
                                   time_ordered=True)
    if window is None:
        return data
    t = data.extra["t"]
    return data.subset((t >= window[0]) & (t < window[1]))


def main() -> casest.Estimate:
    """Estimate the calibration on the whole record and print the report."""
    est = casest.estimate(model(), load(), sweep_settings=SWEEP_SETTINGS)
    print(est.report())
    return est


if __name__ == "__main__":
    main()
