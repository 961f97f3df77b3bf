"""Hard estimation problems for the robustness suite (``scripts/campaigns/robustness.py``).

Each builder returns ``(model, data)``; the data are simulated with a fixed seed (or, for
BoxBOD, are the NIST StRD data). The nominal values are the box midpoints (or the NIST
start), never the truth: the point of the suite is to see whether casest finds the global
maximum-likelihood minimum without a good guess.

- ``boxbod_start1`` / ``boxbod_start2``: NIST StRD BoxBOD, ``y = b1 (1 - exp(-b2 x))``,
  6 observations, from each NIST start with the suite's protocol box on b2.
- ``exp_gauss3``: one exponential and three Gaussian peaks (4 linear amplitudes, 7
  nonlinear rates, centres and widths), wide boxes; the peaks can be relabelled (ties).
- ``exp3``: three decaying exponentials, rates boxed over four decades (log-uniform);
  permuting the terms gives equal cost.
- ``two_tones``: two damped sinusoids sampled at 10 Hz, frequencies boxed up to twice the
  Nyquist frequency, so that every frequency has an alias ``2 pi / dt - w`` with exactly
  the same fit (sine amplitude of opposite sign).
- ``triad``: a three-axis sensor with scale factors ``1 + s`` (``|s| <= 0.1``), biases and a
  mounting angle in ``[-pi, pi]``; channels with different noise. The alias
  ``angle + pi, 1 + s = -1`` fits as well without bounds but is infeasible.
- ``two_site``: a two-site binding curve ``V1 x / (K1 + x) + V2 x / (K2 + x)``, both K
  boxed over six decades (log-uniform); the sites can be swapped.

Run ``python models/robustness.py`` to estimate all of them.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

import casest
from casest.apps.nist import nist_box

# NIST StRD BoxBOD (Box et al. 1978): data, starts and certified values from the NIST file
BOXBOD_X = np.array([1.0, 2.0, 3.0, 5.0, 7.0, 10.0])
BOXBOD_Y = np.array([109.0, 149.0, 149.0, 191.0, 213.0, 224.0])
BOXBOD_STARTS = {1: (1.0, 1.0), 2: (100.0, 0.75)}
BOXBOD_CERTIFIED = {"b1": 2.1380940889e02, "b2": 5.4723748542e-01, "rss": 1.1680088766e03}


def _boxbod(start: int):
    b1, b2, x = ca.SX.sym("b1"), ca.SX.sym("b2"), ca.SX.sym("x")
    s1, s2 = BOXBOD_STARTS[start]
    lo, hi = nist_box(s2)
    model = casest.Model(
        [casest.Parameter("b1", nominal=s1),
         casest.Parameter("b2", lo, hi, s2, prior=casest.LogUniform())],
        ["x"],
        {"y": b1 * (1 - ca.exp(-b2 * x))},
        name=f"boxbod_start{start}",
    )
    return model, casest.Dataset(model, {"x": BOXBOD_X, "y": BOXBOD_Y})


def boxbod_start1():
    """NIST BoxBOD from start 1 (b1 = 1, b2 = 1), b2 in [1e-3, 1e3]."""
    return _boxbod(1)


def boxbod_start2():
    """NIST BoxBOD from start 2 (b1 = 100, b2 = 0.75), b2 in [7.5e-4, 750]."""
    return _boxbod(2)


def exp_gauss3(seed: int = 0):
    """y = a0 exp(-k x) + sum_i a_i exp(-(x - c_i)^2 / w_i^2), x in [1, 250], N = 250."""
    x = np.linspace(1.0, 250.0, 250)
    a = [ca.SX.sym(f"a{i}") for i in range(4)]
    k = ca.SX.sym("k")
    c = [ca.SX.sym(f"c{i}") for i in range(1, 4)]
    w = [ca.SX.sym(f"w{i}") for i in range(1, 4)]
    xs = ca.SX.sym("x")
    y = a[0] * ca.exp(-k * xs) + sum(a[i + 1] * ca.exp(-((xs - c[i]) ** 2) / w[i] ** 2) for i in range(3))
    params = [casest.Parameter(f"a{i}", nominal=0.0) for i in range(4)]
    params += [casest.Parameter("k", 1e-4, 0.1, 0.05)]
    params += [casest.Parameter(f"c{i}", 0.0, 250.0, 125.0) for i in range(1, 4)]
    params += [casest.Parameter(f"w{i}", 3.0, 80.0, 41.5) for i in range(1, 4)]
    model = casest.Model(params, ["x"], {"y": y}, name="exp_gauss3")
    truth = {"a0": 90.0, "k": 0.012, "a1": 85.0, "c1": 70.0, "w1": 14.0, "a2": 95.0, "c2": 125.0, "w2": 22.0,
             "a3": 60.0, "c3": 185.0, "w3": 9.0}
    return model, _simulate(model, truth, {"x": x}, [2.5], seed)


def exp3(seed: int = 0):
    """y = sum_i a_i exp(-k_i t), k_i in [0.01, 100] (log-uniform), t in [0.01, 20], N = 60."""
    t = np.geomspace(0.01, 20.0, 60)
    a = [ca.SX.sym(f"a{i}") for i in range(1, 4)]
    k = [ca.SX.sym(f"k{i}") for i in range(1, 4)]
    ts = ca.SX.sym("t")
    params = [casest.Parameter(f"a{i}", nominal=0.0) for i in range(1, 4)]
    params += [casest.Parameter(f"k{i}", 0.01, 100.0, 1.0, prior=casest.LogUniform()) for i in range(1, 4)]
    model = casest.Model(params, ["t"], {"y": sum(a[i] * ca.exp(-k[i] * ts) for i in range(3))}, name="exp3")
    truth = {"a1": 1.0, "a2": 2.0, "a3": 1.5, "k1": 0.3, "k2": 2.0, "k3": 9.0}
    return model, _simulate(model, truth, {"t": t}, [2e-3], seed)


def two_tones(seed: int = 0):
    """y = sum_i exp(-d_i t) (p_i sin(w_i t) + q_i cos(w_i t)), 10 Hz for 12 s, w_i in [0.5, 60]."""
    dt = 0.1
    t = np.arange(120) * dt
    d = [ca.SX.sym(f"d{i}") for i in (1, 2)]
    w = [ca.SX.sym(f"w{i}") for i in (1, 2)]
    p = [ca.SX.sym(f"p{i}") for i in (1, 2)]
    q = [ca.SX.sym(f"q{i}") for i in (1, 2)]
    ts = ca.SX.sym("t")
    y = sum(ca.exp(-d[i] * ts) * (p[i] * ca.sin(w[i] * ts) + q[i] * ca.cos(w[i] * ts)) for i in range(2))
    params = [casest.Parameter(f"{n}{i}", nominal=0.0) for i in (1, 2) for n in ("p", "q")]
    params += [casest.Parameter(f"d{i}", 0.0, 1.0, 0.5) for i in (1, 2)]
    params += [casest.Parameter(f"w{i}", 0.5, 60.0, 30.25, unit="rad/s") for i in (1, 2)]
    model = casest.Model(params, ["t"], {"y": y}, name="two_tones")
    truth = {"p1": 1.0, "q1": 0.5, "p2": -0.7, "q2": 0.8, "d1": 0.05, "d2": 0.2, "w1": 5.0, "w2": 11.0}
    return model, _simulate(model, truth, {"t": t}, [0.1], seed)


def triad(seed: int = 0):
    """Three-axis sensor: m = diag(1 + s) Rz(psi) H + bias; |s| <= 0.1, psi in [-pi, pi]."""
    rng = np.random.default_rng(1000 + seed)
    N = 200
    heading = rng.uniform(-math.pi, math.pi, N)
    dip = rng.uniform(-1.0, 1.0, N)
    H = np.column_stack([np.cos(dip) * np.cos(heading), np.cos(dip) * np.sin(heading), np.sin(dip)]) * 50.0
    Hx, Hy, Hz, psi = ca.SX.sym("Hx"), ca.SX.sym("Hy"), ca.SX.sym("Hz"), ca.SX.sym("psi")
    s = [ca.SX.sym(f"s{a}") for a in "xyz"]
    bias = [ca.SX.sym(f"b{a}") for a in "xyz"]
    rotated = [ca.cos(psi) * Hx + ca.sin(psi) * Hy, -ca.sin(psi) * Hx + ca.cos(psi) * Hy, Hz]
    outputs = {f"m{a}": (1 + s[i]) * rotated[i] + bias[i] for i, a in enumerate("xyz")}
    params = [casest.Parameter(f"s{a}", -0.1, 0.1, 0.0) for a in "xyz"]
    params += [casest.Parameter(f"b{a}", nominal=0.0, unit="uT") for a in "xyz"]
    params += [casest.Parameter("psi", -math.pi, math.pi, 0.0, unit="rad")]
    model = casest.Model(params, [casest.Signal(n, "uT") for n in ("Hx", "Hy", "Hz")], outputs, name="triad")
    truth = {"sx": 0.03, "sy": -0.05, "sz": 0.02, "bx": 1.0, "by": -2.0, "bz": 0.5, "psi": 2.4}
    return model, _simulate(model, truth, {"Hx": H[:, 0], "Hy": H[:, 1], "Hz": H[:, 2]}, [0.5, 1.0, 2.0], seed)


def two_site(seed: int = 0):
    """y = V1 x / (K1 + x) + V2 x / (K2 + x), K_i in [1e-3, 1e3] (log-uniform), N = 40."""
    x = np.geomspace(1e-3, 1e3, 40)
    V = [ca.SX.sym(f"V{i}") for i in (1, 2)]
    K = [ca.SX.sym(f"K{i}") for i in (1, 2)]
    xs = ca.SX.sym("x")
    params = [casest.Parameter(f"V{i}", nominal=0.0) for i in (1, 2)]
    params += [casest.Parameter(f"K{i}", 1e-3, 1e3, 1.0, prior=casest.LogUniform()) for i in (1, 2)]
    model = casest.Model(params, ["x"], {"y": sum(V[i] * xs / (K[i] + xs) for i in range(2))}, name="two_site")
    truth = {"V1": 1.0, "V2": 3.0, "K1": 0.05, "K2": 20.0}
    return model, _simulate(model, truth, {"x": x}, [0.01], seed)


def _simulate(model, truth, signals, noise_std, seed):
    """Data from the model at ``truth`` plus Gaussian noise (one std per output)."""
    rng = np.random.default_rng(seed)
    X = np.column_stack([signals[n] for n in model.signal_names])
    clean = model.predict(model.vector(truth), X)
    cols = dict(signals)
    for j, name in enumerate(model.output_names):
        cols[name] = clean[:, j] + noise_std[j] * rng.standard_normal(len(X))
    return casest.Dataset(model, cols)


#: the problems simulated with noise (their builders take a ``seed``)
SIMULATED = ("exp_gauss3", "exp3", "two_tones", "triad", "two_site")

#: name -> builder of (model, data)
PROBLEMS = {
    "boxbod_start1": boxbod_start1,
    "boxbod_start2": boxbod_start2,
    "exp_gauss3": exp_gauss3,
    "exp3": exp3,
    "two_tones": two_tones,
    "triad": triad,
    "two_site": two_site,
}


def model() -> casest.Model:
    """The file's default model (two damped tones), for ``scripts/examples/solve.py --data``."""
    return two_tones()[0]


def simulate(seed: int = 0) -> casest.Dataset:
    """Two-tone data with noise of std 0.1 (the file's default)."""
    return two_tones(seed)[1]


def main() -> None:
    for name, build in PROBLEMS.items():
        model, data = build()
        est = casest.estimate(model, data)
        print(f"{name}: J = {est.cost:.10g}, success = {est.success}")


if __name__ == "__main__":
    main()
