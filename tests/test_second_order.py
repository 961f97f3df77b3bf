"""Output error's exact Hessian by the adjoint of the simulation (casest.backend.second_order).

Truth: CasADi's automatic differentiation (forward over reverse) through the simulation graph
of the same discretised cost (``Problem.cost_expression``), to 1e-9 relative to the Hessian's
largest entry, on every structure the Hessian meets: estimated initial states, an initial state read from the data, the cubic
input hold, missing outputs (the mask), a full R (log-Cholesky), two manoeuvres in one record
(the states restart from parameters at a segment's first sample), an input delay and a
record long enough for the sums to run on every core."""

import casadi as ca
import numpy as np
import pytest

import casest
from casest._casadi.numerics import compiler_available
from casest.problem import output_error_sums

P = casest.Parameter
TRUTH = {"a": 0.3, "k": 3.0, "c": 1.7, "d": -0.4, "x0": 0.2, "v0": -0.3, "tau": 0.03}


def _oscillator(initial=("x0", "v0"), **options):
    """x'' = -k x - a x' + u; y1 = c x + d + a x v (an output with a parameter of the dynamics), y2 = x'."""
    x, v, u, a, k, c, d = (ca.SX.sym(n) for n in ("x", "v", "u", "a", "k", "c", "d"))
    params = [P("a", 0.05, 2.0, 0.5), P("k", 0.5, 8.0, 2.0), P("c", -5.0, 5.0, 1.0), P("d", -5.0, 5.0, 0.0)]
    params += [P(name, -1.0, 1.0, 0.0) for name in initial if isinstance(name, str) and name != "data"]
    if "delays" in options:
        params.append(P("tau", 0.0, 0.1, 0.02))
    states = [casest.State("x", initial[0]), casest.State("v", initial[1])]
    return casest.DynamicModel(params, states, ["u"], {"x": v, "v": -k * x - a * v + u ** 3 / 3 + u},
                               {"y1": c * x + d + a * x * v, "y2": v}, name="oscillator", **options)


def _record(model, seed=0, n=150, dt=0.02, missing=False, phase=0.0):
    t = np.arange(n) * dt
    u = np.sin(0.7 * t + phase) + 0.5 * np.sin(2.3 * t) + 0.3 * np.cos(4.1 * t)
    zeros = np.zeros(n)
    from_data = {"v": np.full(n, TRUTH["v0"])} if "data" in [s.initial for s in model.states] else {}
    truth = {name: TRUTH[name] for name in model.parameter_names}
    _, clean = model.simulate(truth, model.dataset({"t": t, "u": u, "y1": zeros, "y2": zeros, **from_data}))
    z = clean + np.random.default_rng(seed).standard_normal(clean.shape) * [0.05, 0.02]
    if missing:
        z[::7, 0] = np.nan
        z[3::11, 1] = np.nan
    return model.dataset({"t": t, "u": u, "y1": z[:, 0], "y2": z[:, 1], **from_data},
                         missing="allow" if missing else "error")


CASES = {
    "initial states, linear hold": lambda: (_oscillator(substeps=2), None),
    "an initial state from the data": lambda: (_oscillator(initial=("x0", "data")), None),
    "cubic hold": lambda: (_oscillator(substeps=2, input_hold="cubic"), None),
    "missing outputs": lambda: (_oscillator(), dict(missing=True)),
    "full R": lambda: (_oscillator(), "full"),
    "two manoeuvres": lambda: (_oscillator(), "segments"),
    "input delay": lambda: (_oscillator(initial=(0.1, 0.0), delays={"u": "tau"}, sample_time=0.02), None),
    "a long record (its sums on every core)": lambda: (_oscillator(), dict(n=700)),
}


def _problem(case):
    model, how = CASES[case]()
    if how == "segments":
        return casest.Problem(model, [_record(model, seed=s, n=90, phase=float(s)) for s in range(2)],
                              separate_noise=False)
    if how == "full":
        return casest.Problem(model, _record(model), noise=casest.CorrelatedNoise())
    return casest.Problem(model, _record(model, **(how or {})))


@pytest.mark.parametrize("case", list(CASES))
def test_the_adjoint_hessian_equals_automatic_differentiation(case):
    problem = _problem(case)
    model, N = problem.model, problem.n_samples
    n, n_noise = model.n_parameters, problem.noise_term.block_size(model.n_outputs)
    sums = output_error_sums(model, N, model.scales, problem.masked, problem.noise_term)
    rng = np.random.default_rng(4)
    theta = model.vector({name: TRUTH[name.split("@")[0]] for name in model.parameter_names}) * 1.05
    w = np.concatenate([theta / model.scales, rng.uniform(-7.0, -5.0, n_noise)])
    p = problem.data_vector()
    ws, ps = ca.MX.sym("w", w.size), ca.MX.sym("p", p.size)
    J = problem.cost_expression(ws[:n] * ca.DM(model.scales), ws[n:], ps) / N
    H_ad = np.asarray(ca.Function("ad", [ws, ps], [ca.hessian(J, ws)[0]])(w, p))
    H = np.asarray(ca.densify(sums.hessian(w, p)))
    H = H + H.T - np.diag(np.diag(H))
    np.testing.assert_allclose(H, H_ad, rtol=1e-9, atol=1e-9 * np.abs(H_ad).max())


@pytest.mark.skipif(not compiler_available(), reason="without a C compiler both are the same uncompiled graph")
def test_the_compiled_adjoint_hessian_equals_the_uncompiled():
    problem = _problem("initial states, linear hold")
    model, N = problem.model, problem.n_samples
    w = np.concatenate([model.vector({k: TRUTH[k] for k in model.parameter_names}) / model.scales, [-6.0, -7.0]])
    p = problem.data_vector()
    plain = np.asarray(output_error_sums(model, N, model.scales).hessian(w, p))
    compiled = np.asarray(output_error_sums(model, N, model.scales, jit=True).hessian(w, p))
    np.testing.assert_allclose(compiled, plain, rtol=1e-12, atol=1e-12 * np.abs(plain).max())
