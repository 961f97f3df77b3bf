"""
EKF and RTS smoother on a pendulum with process noise
=====================================================

The extended Kalman filter of summary Sec. 3 on a pendulum whose rate is disturbed by
process noise, then the Rauch-Tung-Striebel smoother (Eq. 2.20-2.22). The band is two
smoothed standard deviations; the truth is the simulation the measurements were taken from.
"""

import casadi as ca
import matplotlib.pyplot as plt
import numpy as np

import casest
from casest.filters.ekf import ExtendedKalmanFilter, rts_smoother

P = casest.Parameter
ang, rate, torque, damping, length = (ca.SX.sym(n) for n in ("ang", "rate", "torque", "c", "L"))
pendulum = casest.DynamicModel(
    [P("c", 0.0, 2.0, 0.3), P("L", 0.5, 2.0, 1.0)], [casest.State("ang", 1.0), casest.State("rate", 0.0)],
    ["torque"], rhs={"ang": rate, "rate": -9.81 / length * ca.sin(ang) - damping * rate + torque},
    outputs={"px": length * ca.sin(ang), "py": -length * ca.cos(ang)}, substeps=4, input_hold="zoh")
rng = np.random.default_rng(1)
t = np.arange(300) * 0.05
torque_in = 0.5 * np.sin(1.3 * t)
x, truth = np.array([1.0, 0.0]), []
for k in range(t.size):  # Euler-Maruyama in 1 ms steps, process noise on the rate (q = 0.5)
    truth.append(x.copy())
    for _ in range(50):
        acc = -9.81 * np.sin(x[0]) - 0.3 * x[1] + torque_in[k]
        x = x + 0.001 * np.array([x[1], acc]) + [0.0, np.sqrt(0.5 * 0.001) * rng.standard_normal()]
truth = np.array(truth)
bob = np.column_stack([np.sin(truth[:, 0]), -np.cos(truth[:, 0])]) + rng.normal(0, 0.05, (t.size, 2))
swing = pendulum.dataset({"t": t, "torque": torque_in, "px": bob[:, 0], "py": bob[:, 1]})

ekf = ExtendedKalmanFilter(pendulum, {"c": 0.3, "L": 1.0}, {"rate": 0.5}, [0.05**2, 0.05**2], np.eye(2) * 1e-4)
filtered = ekf.filter(swing)
smoothed = rts_smoother(filtered)
print(f"mean NEES filtered {filtered.nees(truth).mean():.2f}, smoothed {smoothed.nees(truth).mean():.2f} "
      "(2 for a consistent estimate of two states)")

fig, axes = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
for j, ax in enumerate(axes):
    ax.plot(t, truth[:, j], "k", lw=1, label="truth")
    ax.plot(t, filtered.x_filtered[:, j], label="EKF")
    ax.fill_between(t, smoothed.x[:, j] - 2 * smoothed.std[:, j], smoothed.x[:, j] + 2 * smoothed.std[:, j],
                    alpha=0.3, label="smoother +- 2 std")
    ax.set_ylabel(pendulum.state_names[j])
axes[0].legend()
axes[-1].set_xlabel("t (s)")
fig.tight_layout()
