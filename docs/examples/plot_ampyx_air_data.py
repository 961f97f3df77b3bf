"""
Air-data calibration on a real flight record (Ampyx AP2)
========================================================

The bundled Ampyx Power AP2 record (Ampyx Power AP2 flight data, courtesy of Ampyx Power B.V.
and the TU Delft Airborne Wind Energy group, Apache License 2.0) read as published, by struct
paths; the paper's air-data error model (``models/ampyx_air_data.py``) estimated by the
two-stage method on the first 32.8 s and validated on the rest. The figures are the
estimate's own: measured against estimated outputs with the residual autocorrelation, the
proof of match on the held-out segment, and the residuals' autocorrelation and prewhitened
cross-correlation with each signal, from which the conclusion says whether the noise is coloured
or the model lacks something. The whole worked example (flight-path
reconstruction and rate responses too) is ``scripts/examples/ampyx_example.py``.
"""

import matplotlib.pyplot as plt

import casest
from casest.estimation.figures import validation_figure

module = casest.load_model_file("ampyx_air_data")
model = module.model()
train, held_out = module.load((0.0, 32.8)), module.load((32.8, 49.4))
est = casest.estimate(model, train, sweep_settings=module.SWEEP_SETTINGS)
choice = est.std_choice()
for name, value, std in zip(est.parameter_names, est.theta, choice.std):
    print(f"{name:>12} = {value:10.4f} +/- {std:.4f}")
print("std:", choice.kind, "-", choice.reason)
code, reason = est.conclusion()  # what the residual tests say: coloured noise, or what the model lacks
print(f"conclusion: {code.value}: {reason}")
print("diagnosis:", est.diagnosis.describe() if est.diagnosis is not None else "none (no candidate change explains it)")
validation = est.validate(model, held_out)
print(validation.report())

fit = plt.figure(est.plot_fit(model, train, title="AP2 air data: s1 + s2"))
match = plt.figure(validation_figure(validation, "s3, held out"))
residuals = plt.figure(est.plot_residuals(model, train))  # autocorrelation and cross-correlation with the signals
