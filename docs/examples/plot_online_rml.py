"""
Recursive maximum likelihood, online
====================================

Recursive ML (summary Sec. 5.3, Eq. 5.10-5.13) on the short-period aircraft model, sample by
sample in time order, with the output-error predictor and its state sensitivities
(``scripts/examples/online_rml.py --dynamic``). It starts 10 % off in every parameter; the figure shows
each parameter's distance from the batch output-error estimate of the whole record, in batch
standard deviations.
"""

import matplotlib.pyplot as plt
import numpy as np

import casest
from casest.recursive import RecursiveML

module = casest.load_model_file("short_period")
model, data = module.model(), module.simulate_random(seed=0, duration=200.0)
batch = casest.estimate(model, data)
R0 = 4.0 * np.array([module.NOISE_STD[n] for n in model.output_names]) ** 2
rml = RecursiveML(model, {k: 1.1 * v for k, v in module.TRUTH.items()}, R0, forgetting=0.9, forgetting_rate=0.995)
history = rml.run(data)
z = (history - batch.theta) / batch.std
print("after the record, in batch std: " + ", ".join(f"{n} {v:+.2f}" for n, v in zip(model.parameter_names, z[-1])))

fig, ax = plt.subplots(figsize=(9, 4))
ax.plot(data.signals[:, 0], np.clip(z, -10, 10), lw=1)
ax.axhspan(-0.5, 0.5, color="k", alpha=0.1)
ax.set_ylim(-10, 10)
ax.set_xlabel("t (s)")
ax.set_ylabel("(theta_RML - theta_batch) / std")
ax.legend(model.parameter_names, ncol=4, fontsize=8)
fig.tight_layout()
