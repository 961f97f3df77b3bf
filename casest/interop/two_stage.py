"""The two-stage estimator as a ``casadi.Function``: data in; theta, R, covariance and a
success flag out, with derivatives with respect to the data from the implicit function
theorem at the optimum."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings, active_bounds
from ..data import Dataset
from ..estimation import SweepSettings, estimate
from ..models import Model, OptionError
from ..problem import ml_cost_expression


__all__ = ["two_stage_function"]


# callbacks live as long as the process: CasADi holds raw pointers to them
_ESTIMATORS: list = []


class _TwoStageEstimator(ca.Callback):
    """``(signals, outputs) -> (theta, R, cov, success)`` by :func:`casest.estimate`, with
    derivatives from the implicit function theorem (see :func:`two_stage_function`)."""

    def __init__(self, name: str, model: Model, n_samples: int, sweep_settings, solver_settings, options: dict):
        ca.Callback.__init__(self)
        self.model, self.N = model, n_samples
        self.sweep_settings, self.solver_settings, self.options = sweep_settings, solver_settings, options
        n, ny = model.n_parameters, model.n_outputs
        self.X = ca.MX.sym("signals", model.n_signals, n_samples)
        self.Z = ca.MX.sym("outputs", ny, n_samples)
        self.theta = ca.MX.sym("theta", n)
        self.rho = ca.MX.sym("rho", ny)
        w = ca.vertcat(self.theta, self.rho)
        J = ml_cost_expression(model, n_samples, self.theta, self.rho, ca.vertcat(ca.vec(self.X), ca.vec(self.Z)))
        self.g = ca.gradient(J, w)
        self.H = ca.jacobian(self.g, w)
        self.newton = ca.Function("two_stage_newton", [w, self.X, self.Z], [self.g, self.H])
        self._jacobian = None
        self.construct(name, {})
        _ESTIMATORS.append(self)

    def get_n_in(self):
        return 2

    def get_n_out(self):
        return 4

    def get_name_in(self, i):
        return ("signals", "outputs")[i]

    def get_name_out(self, i):
        return ("theta", "R", "cov", "success")[i]

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.model.n_signals if i == 0 else self.model.n_outputs, self.N)

    def get_sparsity_out(self, i):
        n, ny = self.model.n_parameters, self.model.n_outputs
        return [ca.Sparsity.dense(n, 1), ca.Sparsity.dense(ny, 1), ca.Sparsity.dense(n, n), ca.Sparsity.dense(1, 1)][i]

    def free_mask(self, theta: np.ndarray) -> np.ndarray:
        """1 for a parameter inside its bounds (and for every ln R_j), 0 for one on a bound."""
        active = active_bounds(theta, self.model.lower_bounds, self.model.upper_bounds, self.model.scales)
        return np.concatenate([[0.0 if a else 1.0 for a in active], np.ones(self.model.n_outputs)])

    def eval(self, args):
        X, Z = np.asarray(args[0], dtype=float), np.asarray(args[1], dtype=float)
        data = Dataset.from_arrays(self.model, X.T, Z.T)
        est = estimate(self.model, data, sweep_settings=self.sweep_settings, solver_settings=self.solver_settings,
                       **self.options)
        n = self.model.n_parameters
        w = np.concatenate([est.theta, np.log(est.R)])
        free = self.free_mask(est.theta).astype(bool)
        # polish with exact Newton steps on the free variables: the derivatives below hold
        # at the exact stationary point, and differences of nearby solves become smooth
        for _ in range(3):
            g, H = (np.asarray(v, dtype=float) for v in self.newton(w, X, Z))
            try:
                step = np.linalg.solve(H[np.ix_(free, free)], -g.reshape(-1)[free])
            except np.linalg.LinAlgError:
                break
            trial = w.copy()
            trial[free] += step
            theta = trial[:n]
            if np.any(theta < self.model.lower_bounds) or np.any(theta > self.model.upper_bounds):
                break
            w = trial
            if np.linalg.norm(step, np.inf) < 1e-15 * max(1.0, np.linalg.norm(w, np.inf)):
                break
        cov = self._covariance(w, X, Z, free)
        return [ca.DM(w[:n]), ca.DM(np.exp(w[n:])), ca.DM(cov), ca.DM(float(bool(est.success)))]

    def _covariance(self, w, X, Z, free) -> np.ndarray:
        n = self.model.n_parameters
        _, H = self.newton(w, X, Z)
        H = np.asarray(H, dtype=float)
        cov = np.zeros_like(H)
        try:
            cov[np.ix_(free, free)] = np.linalg.inv(H[np.ix_(free, free)])
        except np.linalg.LinAlgError:
            cov[:] = np.nan
        return cov[:n, :n]

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        n, ny = self.model.n_parameters, self.model.n_outputs
        X, Z = self.X, self.Z
        theta_o, R_o = ca.MX.sym("theta_o", n), ca.MX.sym("R_o", ny)
        cov_o, success_o = ca.MX.sym("cov_o", n, n), ca.MX.sym("success_o")
        w_o = ca.vertcat(theta_o, ca.log(R_o))
        # parameters on a bound stay there under small changes of the data (zero derivative)
        inside = []
        for i, (lo, hi, sc) in enumerate(zip(self.model.lower_bounds, self.model.upper_bounds, self.model.scales)):
            flag = ca.MX(1)  # the same test as active_bounds, on the bounds that are finite
            if np.isfinite(lo):
                flag = flag * (theta_o[i] - lo > 1e-7 * max(sc, abs(lo)))
            if np.isfinite(hi):
                flag = flag * (hi - theta_o[i] > 1e-7 * max(sc, abs(hi)))
            inside.append(flag)
        mask = ca.vertcat(*inside, ca.DM.ones(ny))
        w = ca.vertcat(self.theta, self.rho)
        D = ca.diag(mask)
        H_masked = ca.mtimes(ca.mtimes(D, self.H), D) + ca.diag(1 - mask)
        cov_w = ca.mtimes(ca.mtimes(D, ca.inv(H_masked)), D)[:n, :n]
        dw = {}
        blocks = {}
        for label, data in (("signals", X), ("outputs", Z)):
            G = ca.mtimes(D, ca.jacobian(self.g, data))
            dw_sym = -ca.solve(H_masked, G)
            dw[label] = ca.substitute(dw_sym, w, w_o)
            dcov = ca.jacobian(ca.vec(cov_w), data) + ca.mtimes(ca.jacobian(ca.vec(cov_w), w), dw_sym)
            blocks[("cov", label)] = ca.substitute(dcov, w, w_o)
            blocks[("theta", label)] = dw[label][:n, :]
            blocks[("R", label)] = ca.mtimes(ca.diag(R_o), dw[label][n:, :])
            blocks[("success", label)] = ca.MX.zeros(1, data.numel())
        outputs = [blocks[(o, i)] for o in ("theta", "R", "cov", "success") for i in ("signals", "outputs")]
        return ca.Function(name, [X, Z, theta_o, R_o, cov_o, success_o], outputs, inames, onames)


def two_stage_function(model: Model, n_samples: int, sweep_settings: SweepSettings | None = None,
                       solver_settings: SolverSettings | None = None, name: str = "two_stage", **options
                       ) -> ca.Function:
    """The two-stage estimator as a ``casadi.Function`` that can sit inside CasADi graphs.

    ``two_stage(signals[n_signals x N], outputs[n_outputs x N]) -> (theta[n], R[n_y],
    cov[n x n], success)``. Its evaluation runs :func:`casest.estimate` (stage 1 sweeps
    xi2, stage 2 starts IPOPT from the best candidates), then polishes the optimum with
    exact Newton steps. Its derivatives with respect to the data come from the implicit
    function theorem at the optimum: with ``w = [theta; ln R]`` and ``g(w, data) = dJ/dw =
    0`` there, ``dw/d data = -H^-1 dg/d data`` (H the exact Hessian of J; parameters on a
    bound held there). ``cov`` is the theta block of ``H^-1`` (rows and columns of
    parameters on a bound are zero); its derivative follows the same chain (third
    derivatives of J). ``success`` is 1.0 when casest stands behind the estimate (its
    derivative is zero).

    Parameters
    ----------
    model : Model
        A static model (unknown diagonal R).
    n_samples : int
        N.
    sweep_settings, solver_settings
        As in :func:`casest.estimate`.
    **options
        Passed on to :func:`casest.estimate` (e.g. ``mode``, ``max_starts``).

    Returns
    -------
    casadi.Function
        Callable numerically and on MX symbols (then its first derivatives are exact at the
        optimum; second derivatives are not offered).
    """
    if not isinstance(model, Model):
        raise OptionError("two_stage_function takes a static casest.Model")
    callback = _TwoStageEstimator(name + "_callback", model, int(n_samples), sweep_settings, solver_settings, options)
    X = ca.MX.sym("signals", model.n_signals, int(n_samples))
    Z = ca.MX.sym("outputs", model.n_outputs, int(n_samples))
    out = callback(X, Z)
    return ca.Function(name, [X, Z], list(out), ["signals", "outputs"], ["theta", "R", "cov", "success"])
