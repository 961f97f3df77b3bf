"""NumPy residuals and hand-written Jacobians of the stage-2 comparison problems (the SciPy and lmfit peers).

A competent user of SciPy or lmfit writes the model and its Jacobian in NumPy; the peers of
``scripts/benchmarks/bench.py --parts stage2`` use these, never a CasADi call. Each Jacobian is checked
against casest's at the start (:func:`checked_problem`) so that a slip here cannot flatter or
handicap anyone.

Problems: the bundled NIST StRD models (by the model's name), scalar 2 (paper Eq. 33) and the
5-hole Pitot probe (paper Eq. 36-41).
"""

from __future__ import annotations

import numpy as np

TWO_PI = 2.0 * np.pi


def _nist(name: str, x: np.ndarray):
    """``f(b) -> (prediction (N,), jacobian())`` of a NIST model in NumPy: the Jacobian (N, p) is
    computed when ``jacobian()`` is called, from the prediction's shared terms."""

    def misra1a(b):
        e = np.exp(-b[1] * x)
        return b[0] * (1 - e), lambda: np.column_stack([1 - e, b[0] * x * e])

    def chwirut2(b):
        e, d = np.exp(-b[0] * x), b[1] + b[2] * x
        return e / d, lambda: np.column_stack([-x * e / d, -e / d**2, -x * e / d**2])

    def danwood(b):
        p = x ** b[1]
        return b[0] * p, lambda: np.column_stack([p, b[0] * p * np.log(x)])

    def enso(b):
        a12, a4, a7 = TWO_PI * x / 12, TWO_PI * x / b[3], TWO_PI * x / b[6]
        f = (b[0] + b[1] * np.cos(a12) + b[2] * np.sin(a12) + b[4] * np.cos(a4) + b[5] * np.sin(a4)
             + b[7] * np.cos(a7) + b[8] * np.sin(a7))
        d4 = TWO_PI * x / b[3] ** 2 * (b[4] * np.sin(a4) - b[5] * np.cos(a4))
        d7 = TWO_PI * x / b[6] ** 2 * (b[7] * np.sin(a7) - b[8] * np.cos(a7))
        J = lambda: np.column_stack(  # noqa: E731  (the Jacobian when asked)
            [np.ones_like(x), np.cos(a12), np.sin(a12), d4, np.cos(a4), np.sin(a4), d7, np.cos(a7),
                             np.sin(a7)])
        return f, J

    def eckerle4(b):
        t = (x - b[2]) / b[1]
        e = np.exp(-0.5 * t**2)
        return b[0] / b[1] * e, lambda: np.column_stack([e / b[1], b[0] * e / b[1] ** 2 * (t**2 - 1), b[0] * e * t / b[1] ** 2])

    def gauss(b):
        e = np.exp(-b[1] * x)
        g1, g2 = np.exp(-((x - b[3]) ** 2) / b[4] ** 2), np.exp(-((x - b[6]) ** 2) / b[7] ** 2)
        f = b[0] * e + b[2] * g1 + b[5] * g2
        J = lambda: np.column_stack(  # noqa: E731  (the Jacobian when asked)
            [e, -b[0] * x * e, g1, b[2] * g1 * 2 * (x - b[3]) / b[4] ** 2,
                             b[2] * g1 * 2 * (x - b[3]) ** 2 / b[4] ** 3, g2, b[5] * g2 * 2 * (x - b[6]) / b[7] ** 2,
                             b[5] * g2 * 2 * (x - b[6]) ** 2 / b[7] ** 3])
        return f, J

    def kirby2(b):
        n, d = b[0] + b[1] * x + b[2] * x**2, 1 + b[3] * x + b[4] * x**2
        return n / d, lambda: np.column_stack([1 / d, x / d, x**2 / d, -n * x / d**2, -n * x**2 / d**2])

    def lanczos3(b):
        e = [np.exp(-b[2 * i + 1] * x) for i in range(3)]
        J = lambda: np.column_stack(  # noqa: E731  (the Jacobian when asked)
            [c for i in range(3) for c in (e[i], -b[2 * i] * x * e[i])])
        return sum(b[2 * i] * e[i] for i in range(3)), J

    def mgh09(b):
        n, d = x**2 + x * b[1], x**2 + x * b[2] + b[3]
        return b[0] * n / d, lambda: np.column_stack([n / d, b[0] * x / d, -b[0] * n * x / d**2, -b[0] * n / d**2])

    def rat42(b):
        e = np.exp(b[1] - b[2] * x)
        return b[0] / (1 + e), lambda: np.column_stack([1 / (1 + e), -b[0] * e / (1 + e) ** 2, b[0] * x * e / (1 + e) ** 2])

    def thurber(b):
        powers = np.column_stack([x**k for k in range(4)])
        n, d = powers @ b[:4], 1 + powers[:, 1:] @ b[4:]
        return n / d, lambda: np.hstack([powers / d[:, None], -(n / d**2)[:, None] * powers[:, 1:]])

    table = {"Misra1a": misra1a, "Chwirut2": chwirut2, "DanWood": danwood, "ENSO": enso, "Eckerle4": eckerle4,
             "Gauss1": gauss, "Gauss2": gauss, "Kirby2": kirby2, "Lanczos3": lanczos3, "MGH09": mgh09,
             "Rat42": rat42, "Thurber": thurber}
    return table[name]


def _scalar1(eta: np.ndarray):
    def f(b):
        c, s = np.cos(eta + b[1]), np.sin(eta + b[1])
        return (1 + b[0]) * c + b[2], lambda: np.column_stack([c, -(1 + b[0]) * s, np.ones_like(eta)])

    return f


def _scalar2(eta: np.ndarray):
    def f(b):
        arg = eta * (1 + b[1]) + b[2]
        c, s = np.cos(arg), np.sin(arg)
        return (1 + b[0]) * c + b[3], lambda: np.column_stack([c, -(1 + b[0]) * s * eta, -(1 + b[0]) * s, np.ones_like(eta)])

    return f


def _pitot(module, signals: np.ndarray):
    """The wind triangle of ``models/pitot5hole.py`` and its Jacobian (outputs sample-major)."""
    from casest.apps.sim.flight import dcm_body_to_ned

    cols = {n: signals[:, k] for k, (n, _) in enumerate(module.SIGNALS)}
    qc = cols["P_t"] - cols["P_s"]
    speed = np.sqrt(2 * qc / module.RHO)
    pa, pb, deg = cols["P_alpha"] / (module.K_ALPHA * qc), cols["P_beta"] / (module.K_BETA * qc), module.DEG
    C = np.array([dcm_body_to_ned(a, b, c) for a, b, c in zip(cols["phi"], cols["theta"], cols["psi"])])
    omega = np.column_stack([cols["p"] - cols["b_gx"], cols["q"] - cols["b_gy"], cols["r"] - cols["b_gz"]])
    lever = np.einsum("nij,nj->ni", C, np.cross(omega, np.asarray(module.LEVER_ARM)))
    N = signals.shape[0]

    def f(b):
        lv, bv, la, ba, lb, bb, eps = b[:7]
        va = (1 + lv) * speed + bv
        al, be = ((1 + la) * pa + ba) * deg, ((1 + lb) * pb + bb) * deg
        ca_, sa, cb, sb, ce, se = np.cos(al), np.sin(al), np.cos(be), np.sin(be), np.cos(eps), np.sin(eps)
        d = np.column_stack([ca_ * cb, sb, sa * cb])
        d_alpha, d_beta = np.column_stack([-sa * cb, 0 * sa, ca_ * cb]), np.column_stack([-ca_ * sb, cb, -sa * sb])

        def c_eps(v):  # C(eps) v, row-wise
            return np.column_stack([v[:, 0], ce * v[:, 1] + se * v[:, 2], -se * v[:, 1] + ce * v[:, 2]])

        def ned(v):  # C_b^n v, row-wise
            return np.einsum("nij,nj->ni", C, v)

        u = ned(c_eps(d))
        h = va[:, None] * u - lever + b[7:10]

        def jacobian():
            du_alpha, du_beta = ned(c_eps(d_alpha)), ned(c_eps(d_beta))
            du_eps = ned(np.column_stack([0 * d[:, 0], -se * d[:, 1] + ce * d[:, 2], -ce * d[:, 1] - se * d[:, 2]]))
            J = np.zeros((N, 3, 10))
            J[:, :, 0], J[:, :, 1] = speed[:, None] * u, u
            J[:, :, 2], J[:, :, 3] = (va * pa * deg)[:, None] * du_alpha, (va * deg)[:, None] * du_alpha
            J[:, :, 4], J[:, :, 5] = (va * pb * deg)[:, None] * du_beta, (va * deg)[:, None] * du_beta
            J[:, :, 6] = va[:, None] * du_eps
            J[:, :, 7:] = np.eye(3)
            return J.reshape(N * 3, 10)

        return h.reshape(-1), jacobian

    return f


def numpy_problem(model, data, pitot_module=None):
    """``(residual(theta), jacobian(theta))`` in NumPy, sample-major rows (z - h sign: h - z); the
    Jacobian is computed only when asked (at the last residual's point, from its shared terms).

    Parameters
    ----------
    model : casest.Model
        One of the comparison problems (NIST by name, ``scalar1``, ``scalar2``, ``pitot5hole``).
    data : casest.Dataset
    pitot_module : module, optional
        ``models/pitot5hole.py`` loaded, for the Pitot problem.
    """
    name = model.name.split(" (")[0]
    if name == "scalar1":
        f = _scalar1(data.signals[:, 0])
    elif name == "scalar2":
        f = _scalar2(data.signals[:, 0])
    elif name == "pitot5hole":
        f = _pitot(pitot_module, data.signals)
    else:
        f = _nist(name, data.signals[:, 0])
    z = data.outputs.reshape(-1)
    last = {}  # the last residual's point and its Jacobian, computed only when the solver asks for it

    def residual(theta):
        theta = np.array(theta, dtype=float)
        prediction, last["jacobian"] = f(theta)
        last["theta"] = theta
        return prediction - z

    def jacobian(theta):
        theta = np.asarray(theta, dtype=float)
        if "theta" not in last or not np.array_equal(theta, last["theta"]):
            residual(theta)
        return last["jacobian"]()

    return residual, jacobian


def checked_problem(model, data, theta, pitot_module=None, rtol: float = 1e-7):
    """:func:`numpy_problem`, after checking its residual and Jacobian against casest's at ``theta``."""
    from casest.backend.sums import prediction_and_jacobian

    residual, jacobian = numpy_problem(model, data, pitot_module)
    h, J = prediction_and_jacobian(model, data.signals, np.asarray(theta, dtype=float))
    r_ref = h - data.outputs.reshape(-1)
    scale = max(1.0, float(np.max(np.abs(r_ref))))
    if not np.allclose(residual(theta), r_ref, rtol=rtol, atol=rtol * scale):
        raise AssertionError(f"the NumPy residual of {model.name} differs from casest's")
    if not np.allclose(jacobian(theta), J, rtol=rtol, atol=rtol * max(1.0, float(np.max(np.abs(J))))):
        raise AssertionError(f"the NumPy Jacobian of {model.name} differs from casest's")
    return residual, jacobian
