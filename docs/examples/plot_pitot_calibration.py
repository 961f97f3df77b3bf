"""
5-hole Pitot-tube calibration
=============================

The flight-test example of the paper (Sec. IV): the calibration model of
``models/pitot5hole.py`` on its simulated flight (``scripts/paper/pitot_calibration.py`` reproduces
the paper's figures). Shown: the estimate and the airspeed residuals against time.
"""

import matplotlib.pyplot as plt

import casest

module = casest.load_model_file("pitot5hole")
model, data = module.model(), module.simulate(seed=0)
est = casest.estimate(model, data)
print(est.report().split("[[Correlations]]")[0])

residuals = data.outputs - model.predict(est.theta, data.signals)
fig, axes = plt.subplots(len(model.output_names), 1, figsize=(9, 2.2 * len(model.output_names)), sharex=True)
for j, ax in enumerate(axes):
    ax.plot(residuals[:, j], ".", ms=2)
    ax.set_ylabel(model.output_names[j])
axes[0].set_title("residuals at the estimate")
axes[-1].set_xlabel("sample")
fig.tight_layout()
