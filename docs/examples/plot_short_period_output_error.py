"""
Output error on an aircraft's short-period motion
=================================================

A :class:`casest.DynamicModel` (``models/short_period.py``): two states driven by the
elevator, three measured outputs with sensor biases. The two-stage estimator runs through
the simulated states (output error, summary Sec. 5.2); the figure compares the measured and
estimated outputs.
"""

import matplotlib.pyplot as plt

import casest

module = casest.load_model_file("short_period")
model, data = module.model(), module.simulate(seed=0)
est = casest.estimate(model, data)
print(est.report().split("[[Correlations]]")[0])

_, predicted = model.simulate(est.theta, data)
t = data.signals[:, 0]
fig, axes = plt.subplots(3, 1, figsize=(9, 6), sharex=True)
for j, ax in enumerate(axes):
    ax.plot(t, data.outputs[:, j], ".", ms=2, label="measured")
    ax.plot(t, predicted[:, j], label="estimated model")
    ax.set_ylabel(model.output_names[j])
axes[0].legend()
axes[-1].set_xlabel("t (s)")
fig.tight_layout()
