"""Summary Sec. 5.2: Newton-Raphson (Eq. 5.8-5.9) and Gauss-Newton against what casest solves.

casest's stage 2 minimises the same ML cost V (Eq. 5.7; paper Eq. 6) with IPOPT and the exact
Hessian: Newton-Raphson with a line search, barrier and bounds; the output-error solver and
``covariance="gauss-newton"`` use the Gauss-Newton matrix M = sum J' R^-1 J (the Fisher
information of Eq. 5.9's remark). Truths, on scalar 2 with R held at its ML value: (1) plain
Eq. 5.8-5.9 (alpha = 1) from a perturbed start reaches casest's optimum with quadratic
convergence; (2) the Gauss-Newton iteration reaches the same point, linearly; (3) at the optimum
M and the exact Hessian differ only by the residual-weighted second derivatives, a few percent
here, and both give the std casest reports for the respective ``covariance`` option.
"""

import casadi as ca
import numpy as np

import casest
from casest.problem.measurement import measurement_of


def cost_functions(problem, R):
    theta = ca.MX.sym("theta", problem.model.n_parameters)
    p = ca.MX.sym("p", problem.data_vector().size)
    V = problem.cost_expression(theta, ca.DM(np.log(R)), p)
    H, g = ca.hessian(V, theta)
    return ca.Function("newton", [theta, p], [V, g, H])


def test_newton_raphson_and_gauss_newton_reach_casests_optimum():
    module = casest.load_model_file("scalar2")
    model = module.model()
    data = module.simulate(0, n=400)
    est = casest.estimate(model, data)
    problem = casest.Problem(model, data)
    f = cost_functions(problem, est.R)
    p = problem.data_vector()
    start = est.theta + np.array([0.02, -0.005, 0.02, -0.02])
    theta, errors = start.copy(), []
    for _ in range(6):  # Eq. 5.8 with alpha = 1 and the Newton-Raphson direction of Eq. 5.9
        _, g, H = (np.asarray(v) for v in f(theta, p))
        theta = theta - np.linalg.solve(H, g.reshape(-1))
        errors.append(np.max(np.abs(theta - est.theta) / est.std))
    assert errors[-1] < 1e-6, errors
    # quadratic: measured 1.6e-2 -> 4.4e-6 std, then casest's own optimum's accuracy (7.5e-10); a Gauss-Newton
    # step from the same start goes 8.4e-3 -> 1.3e-4, above the square of its error
    assert errors[1] < errors[0] ** 2, errors
    theta, gn_errors = start.copy(), []
    for _ in range(30):  # Gauss-Newton: the Fisher information instead of the Hessian
        h, J = measurement_of(model).prediction_and_jacobian(theta, data)
        r = data.outputs.reshape(-1) - h
        M = J.T @ J / est.R[0]
        theta = theta + np.linalg.solve(M, J.T @ r / est.R[0])
        gn_errors.append(np.max(np.abs(theta - est.theta) / est.std))
    assert gn_errors[-1] < 1e-6, gn_errors
    # at the optimum: M against the exact Hessian, and the std of both covariance options
    _, _, H = (np.asarray(v) for v in f(est.theta, p))
    h, J = measurement_of(model).prediction_and_jacobian(est.theta, data)
    M = J.T @ J / est.R[0]
    assert np.max(np.abs(M - H)) / np.max(np.abs(H)) < 0.05
    gauss = casest.estimate(model, data, covariance="gauss-newton")
    np.testing.assert_allclose(gauss.std, np.sqrt(np.diag(np.linalg.inv(M))), rtol=2e-3)
