"""
The paper's two scalar examples
===============================

Scalar examples 1 and 2 of the paper (Sec. III, Eq. 21 and 33), simulated with a fixed seed
(``models/scalar1.py``, ``models/scalar2.py``; ``scripts/campaigns/monte_carlo.py`` runs the 1000-run
campaigns of Tables 1-4). Stage 1 sweeps xi2, stage 2 maximises the likelihood; the stage-1
landscape Tr[R(xi2)] shows one clear minimum, and the paper's error bracket of Eq. 7 holds.
"""

import matplotlib.pyplot as plt
import numpy as np

import casest

fig, axes = plt.subplots(1, 2, figsize=(10, 4))
for ax, name in zip(axes, ("scalar1", "scalar2")):
    module = casest.load_model_file(name)
    est = casest.estimate(module.model(), module.simulate(seed=0))
    print(f"{name}: " + ", ".join(f"{n} = {v:.4f} +- {s:.4f}" for n, v, s in
                                  zip(est.parameter_names, est.theta, est.std)))
    bound = est.landscape.error_bound
    print(f"  Eq. 7 bracket [{bound.lower:.3f}, {bound.stage1_cost:.3f}], J* = {est.cost:.3f}: "
          f"{bound.side(est.cost)}")
    land = est.landscape
    if land.candidates.shape[1] == 1:
        order = np.argsort(land.candidates[:, 0])
        ax.plot(land.candidates[order, 0], land.trace_R[order])
        ax.axvline(module.TRUTH[land.nonlinear[0]], color="k", ls="--", label="truth")
        ax.set_xlabel(land.nonlinear[0]); ax.set_ylabel("Tr[R]")
    else:
        shape = land.grid_shape
        grid = land.candidates[: np.prod(shape)]
        c = ax.contourf(grid[:, 0].reshape(shape), grid[:, 1].reshape(shape),
                        np.log10(land.trace_R[: np.prod(shape)]).reshape(shape), 30)
        fig.colorbar(c, ax=ax, label="log10 Tr[R]")
        ax.plot(module.TRUTH["b"], module.TRUTH["c"], "k+", ms=12, label="truth")
        ax.set_xlabel("b"); ax.set_ylabel("c")
    ax.set_title(f"{name}: stage-1 landscape ({land.verdict})")
    ax.legend()
fig.tight_layout()
