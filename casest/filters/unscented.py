"""The unscented Kalman filter on the states of a :class:`casest.DynamicModel` (Julier and
Uhlmann; van der Merwe's scaled sigma points, as filterpy's ``MerweScaledSigmaPoints``).

The 2n + 1 sigma points ``x, x + U_k, x - U_k`` with ``U`` the upper Cholesky factor of
``(n + lambda) P`` (its rows), ``lambda = alpha^2 (n + kappa) - n``, go through the model's
discrete step (the state's propagation) and its outputs (the measurement); the weights are
``W_m0 = lambda / (n + lambda)``, ``W_c0 = W_m0 + 1 - alpha^2 + beta``, ``W_i = 1 / (2 (n + lambda))``.
The process noise is additive, ``Q_d = Q_c dt``, and the measurement update draws its sigma
points afresh from the prediction's mean and covariance (Q included), as filterpy 2 does. Each prediction records the statistically linearised transition
``Phi = C' P^-1`` (C the cross covariance of the sigma points before and after the step), so
that :func:`casest.filters.rts_smoother` on the result is the unscented RTS smoother.
"""

from __future__ import annotations


import casadi as ca
import numpy as np

from .._casadi.memory import StructureCache
from .._casadi.symbolic_algebra import ldl_solver
from ..backend.ipopt import SolverSettings
from ..data.dataset import Dataset
from ..models import OptionError
from ..models.dynamic import DynamicModel
from .compiled_passes import check_likelihood, filter_rows, mark_missing, run_record, square_matrices
from .filter_records import FilterResult
from .ekf import rts_smoother
from .model_filter import ModelFilter

__all__ = ["UnscentedKalmanFilter", "merwe_weights"]

LOG_2PI = float(np.log(2 * np.pi))
#: the filter's CasADi functions per model structure and sigma-point weights
_UKF_FUNCTIONS = StructureCache()


def merwe_weights(n: int, alpha: float, beta: float, kappa: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Van der Merwe's scaled sigma-point weights.

    Parameters
    ----------
    n : int
        The state's dimension.
    alpha, beta, kappa : float

    Returns
    -------
    lam : float
        ``alpha^2 (n + kappa) - n``.
    Wm, Wc : ndarray, shape (2n + 1,)
        Weights of the mean and of the covariance.
    """
    lam = alpha**2 * (n + kappa) - n
    Wm = np.full(2 * n + 1, 0.5 / (n + lam))
    Wc = Wm.copy()
    Wm[0] = lam / (n + lam)
    Wc[0] = lam / (n + lam) + (1.0 - alpha**2 + beta)
    return lam, Wm, Wc


def _jittered(P):
    """P with a jitter of 1e-14 of its mean variance (1e-300 at least) on the diagonal: the Cholesky
    factor of a state known exactly (P = 0) or in some direction (P singular) exists."""
    n = P.size1()
    return P + (1e-14 * ca.trace(P) / n + 1e-300) * ca.SX.eye(n)


def _sigma_points(x, P, lam: float):
    """The 2n + 1 sigma points as the columns of an (n, 2n + 1) SX matrix."""
    n = x.numel()
    U = ca.chol((n + lam) * _jittered(P))  # upper: U' U = (n + lambda) P; its rows are the offsets
    return ca.horzcat(x, *[x + U[k, :].T for k in range(n)], *[x - U[k, :].T for k in range(n)])


def _weighted(points, Wm, Wc):
    """Mean and centred points of sigma points (columns)."""
    mean = ca.mtimes(points, ca.DM(Wm))
    return mean, points - ca.repmat(mean, 1, points.size2())


def _functions(model: DynamicModel, alpha: float, beta: float, kappa: float) -> dict:
    """``predict``, ``update`` and ``points`` as CasADi functions, cached on the model per weights."""
    cache = _UKF_FUNCTIONS.setdefault(model, {})
    key = (alpha, beta, kappa)
    if key in cache:
        return cache[key]
    n, ny, nu, npar = model.n_states, model.n_outputs, len(model.inputs), model.n_parameters
    lam, Wm, Wc = merwe_weights(n, alpha, beta, kappa)
    step = model.step_function
    nuk = step.size1_in(1)
    x, P, Qc = ca.SX.sym("x", n), ca.SX.sym("P", n, n), ca.SX.sym("Qc", n, n)
    ua, ub, dt, theta = ca.SX.sym("u_a", nuk), ca.SX.sym("u_b", nuk), ca.SX.sym("dt"), ca.SX.sym("theta", npar)
    th = ca.vertcat(*[theta[i] for i in model.rhs_parameter_index]) if model.rhs_parameter_index else ca.SX(0, 1)
    points = _sigma_points(x, P, lam)
    moved = ca.horzcat(*[step(points[:, j], ua, ub, dt, th) for j in range(2 * n + 1)])
    x_prior, d_prior = _weighted(moved, Wm, Wc)
    d_before = points - ca.repmat(x, 1, 2 * n + 1)
    P_prior = ca.mtimes([d_prior, ca.diag(ca.DM(Wc)), d_prior.T]) + Qc * dt
    C = ca.mtimes([d_before, ca.diag(ca.DM(Wc)), d_prior.T])  # cross covariance x(k), x(k+1)
    Phi = ca.solve(_jittered(P), C).T  # the statistically linearised transition, C' P^-1
    predict = ca.Function("ukf_predict", [x, P, ua, ub, dt, theta, Qc], [x_prior, 0.5 * (P_prior + P_prior.T), Phi])
    y, m, u, R = ca.SX.sym("y", ny), ca.SX.sym("m", ny), ca.SX.sym("u", nu), ca.SX.sym("R", ny, ny)
    xp, Pp = ca.SX.sym("x_prior", n), ca.SX.sym("P_prior", n, n)
    sig = _sigma_points(xp, Pp, lam)
    out = model.output_model.function
    heard = ca.horzcat(*[out(ca.vertcat(sig[:, j], u), theta) for j in range(2 * n + 1)])
    z, d_h = _weighted(heard, Wm, Wc)
    d_x = sig - ca.repmat(xp, 1, 2 * n + 1)
    M = ca.diag(m)
    S = ca.mtimes([d_h, ca.diag(ca.DM(Wc)), d_h.T]) + R
    Sm = ca.mtimes([M, S, M]) + ca.diag(1 - m)  # the measured channels; the others cut out
    Pxz = ca.mtimes([d_x, ca.diag(ca.DM(Wc)), d_h.T, M])
    solve, quadratic, logdet, _ = ldl_solver(Sm)  # one factor for the gain and the likelihood
    K = solve(Pxz.T).T
    e = m * (y - z)
    x_post = xp + ca.mtimes(K, e)
    P_post = Pp - ca.mtimes(K, Pxz.T)  # = Pp - K Sm K', as K Sm = Pxz
    ll = -0.5 * (quadratic(e) + logdet + ca.sum1(m) * LOG_2PI)
    update = ca.Function("ukf_update", [xp, Pp, y, m, u, theta, R], [x_post, 0.5 * (P_post + P_post.T), e, S, ll])
    cache[key] = {"predict": predict, "update": update, "weights": (lam, Wm, Wc)}
    return cache[key]


def _pass_step(model: DynamicModel, fns: dict) -> ca.Function:
    """``(acc = [x(k|k-1); vec P(k|k-1)], d_k, c) -> (acc_next, record_k)`` for the compiled pass,
    ``d_k = [y (NaN as 0); mask; u; u_a; u_b; dt]``, ``c = [theta; vec Qc; vec R]``,
    ``record_k = [x(k|k); vec P(k|k); e; vec S; ll; vec Phi]``."""
    n, ny, nu, npar = model.n_states, model.n_outputs, len(model.inputs), model.n_parameters
    nuk = model.step_function.size1_in(1)
    acc, d = ca.SX.sym("acc", n + n * n), ca.SX.sym("d", 2 * ny + nu + 2 * nuk + 1)
    c = ca.SX.sym("c", npar + n * n + ny * ny)
    xp, Pp = ca.vertsplit(acc, [0, n, n + n * n])
    y, m, u, ua, ub, dt = ca.vertsplit(d, np.cumsum([0, ny, ny, nu, nuk, nuk, 1]).tolist())
    theta, Qc, R = ca.vertsplit(c, np.cumsum([0, npar, n * n, ny * ny]).tolist())
    x, P, e, S, ll = fns["update"](xp, ca.reshape(Pp, n, n), y, m, u, theta, ca.reshape(R, ny, ny))
    x_next, P_next, Phi = fns["predict"](x, P, ua, ub, dt, theta, ca.reshape(Qc, n, n))
    record = ca.vertcat(x, ca.vec(P), e, ca.vec(S), ll, ca.vec(Phi))
    return ca.Function("ukf_sample", [acc, d, c], [ca.vertcat(x_next, ca.vec(P_next)), record],
                       ["acc", "d", "c"], ["acc_next", "record"])


def check_sigma_parameters(n: int, alpha, beta, kappa) -> None:
    """Refuse sigma-point parameters outside their ranges: ``0 < alpha <= 1``, ``beta >= 0``,
    ``kappa`` with ``0 < alpha^2 (n + kappa) <= 3 n``: the points lie ``sqrt(alpha^2 (n + kappa))``
    standard deviations from the mean, and beyond ``sqrt(3 n)`` they sample the model far outside
    the state's distribution (alpha = 1e6 put them 1e6 std out, where the filter stopped following
    the measurements)."""
    numbers = all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
                  and np.isfinite(v) for v in (alpha, beta, kappa))
    spread = alpha**2 * (n + kappa) if numbers else np.nan
    if not (numbers and 0 < alpha <= 1 and beta >= 0 and 0 < spread <= 3 * n):
        raise OptionError(f"sigma points need 0 < alpha <= 1, beta >= 0 and 0 < alpha^2 (n + kappa) <= 3 n = {3 * n} "
                          f"(n = {n} states); got alpha={alpha!r}, beta={beta!r}, kappa={kappa!r}. Usual: alpha "
                          "1e-3 to 1, beta = 2 (Gaussian), kappa = 0 or 3 - n")


class UnscentedKalmanFilter(ModelFilter):
    """The unscented Kalman filter on the states of a :class:`casest.DynamicModel` (module docstring).

    Parameters
    ----------
    model : DynamicModel
    theta : mapping or array_like, shape (n_parameters,)
        Parameter values.
    process_noise : mapping, array_like (n,) or (n, n)
        Continuous white-noise intensity on the rhs (:func:`casest.filters.process_noise_matrix`);
        the discrete noise of an interval dt is ``Q_c dt``.
    R : array_like, shape (n_outputs,) or (n_outputs, n_outputs)
        Measurement-noise covariance.
    P0 : array_like, shape (n,) or (n, n)
        Covariance of the initial state.
    x0 : array_like, shape (n,), optional
        Initial state mean; default the model's initial state for the record.
    alpha, beta, kappa : float
        Van der Merwe's sigma-point parameters: the spread ``0 < alpha <= 1`` (usually 1e-3 to
        1), the prior knowledge of the distribution ``beta >= 0`` (2 for a Gaussian), the
        secondary scaling ``kappa`` (usually 0 or 3 - n), with
        ``0 < alpha^2 (n + kappa) <= 3 n`` (:func:`check_sigma_parameters`).

    Examples
    --------
    >>> import numpy as np
    >>> import casest
    >>> m = casest.load_model_file("short_period")
    >>> model, data = m.model(), m.simulate(seed=0)
    >>> R = [m.NOISE_STD[n] ** 2 for n in model.output_names]
    >>> Q, P0 = {"q": 1e-4}, np.eye(2) * 1e-6
    >>> ukf = casest.UnscentedKalmanFilter(model, m.TRUTH, Q, R, P0)
    >>> ukf.filter(data).x_filtered.shape
    (1001, 2)
    """

    kind = "the UKF"

    def __init__(self, model: DynamicModel, theta, process_noise, R, P0, x0=None, alpha: float = 1e-3,
                 beta: float = 2.0, kappa: float = 0.0):
        super().__init__(model, theta, process_noise, R, P0, x0)
        check_sigma_parameters(model.n_states, alpha, beta, kappa)
        self._fns = _functions(model, float(alpha), float(beta), float(kappa))
        self.weights = self._fns["weights"]

    def predict(self, dt: float, u_start, u_end=None, u_now=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Time update over ``dt`` seconds: the sigma points through the model's step.

        Parameters
        ----------
        dt : float
            Interval (s).
        u_start, u_end : array_like
            The step function's input arguments for the interval (as
            :meth:`casest.ExtendedKalmanFilter.predict`).
        u_now : array_like, optional
            Not used (the UKF takes no input noise); the step API's argument.

        Returns
        -------
        x : ndarray, shape (n_states,)
        P : ndarray, shape (n_states, n_states)
        Phi : ndarray, shape (n_states, n_states)
            The statistically linearised transition ``C' P^-1``.
        """
        self._require_state()
        ua = np.asarray(u_start, dtype=float).reshape(-1)
        ub = ua if u_end is None else np.asarray(u_end, dtype=float).reshape(-1)
        x, P, Phi = self._fns["predict"](self.x, self.P, ua, ub, float(dt), self.theta, self.Qc)
        self.x, self.P = np.asarray(x).reshape(-1), np.asarray(P)
        return self.x, self.P, np.asarray(Phi)

    def update(self, y, u) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, int]:
        """Measurement update with y(k) (NaN channels skipped) and the input u(k), from sigma points
        drawn from the current x and P.

        Parameters
        ----------
        y : array_like, shape (n_outputs,)
        u : array_like, shape (n_inputs,)

        Returns
        -------
        x, P, innovation, S, log_likelihood, iterations
            As :meth:`casest.ExtendedKalmanFilter.update` (one iteration).
        """
        self._require_state()
        y, u = self._sample(y, u)
        seen = np.isfinite(y)
        x, P, e, S, ll = self._fns["update"](self.x, self.P, np.where(seen, y, 0.0), seen.astype(float), u,
                                             self.theta, self.R)
        self.x, self.P = np.asarray(x).reshape(-1), np.asarray(P)
        return self.x, self.P, np.where(seen, np.asarray(e).reshape(-1), np.nan), np.asarray(S), float(ll), 1

    def sample_function(self):
        """The UKF's sample as one CasADi Function (:meth:`ModelFilter.sample_function`;
        ``c = [theta; vec Qc; vec R]``, the record ends with vec Phi, the statistically
        linearised transition).

        Returns
        -------
        casadi.Function
        """
        cache = _UKF_FUNCTIONS.setdefault(self.model, {})
        key = ("pass", id(self._fns))
        if key not in cache:
            cache[key] = _pass_step(self.model, self._fns)
        return cache[key]

    def _compiled_pass(self, data: Dataset, x0: np.ndarray, out: tuple | None = None) -> FilterResult:
        """The record as one compiled recursion (the sigma-point step in one C loop)."""
        model, N = self.model, data.n_samples
        n, ny = model.n_states, model.n_outputs
        step = self.sample_function()
        D, seen = filter_rows(model, data)
        t = data.signals[:, 0]
        c = np.concatenate([self.theta, self.Qc.reshape(-1, order="F"), self.R.reshape(-1, order="F")])
        acc0 = np.concatenate([x0, self.P0.reshape(-1, order="F")])
        accs, fields = run_record(step, acc0, D, c, compiled=SolverSettings().record_loop(N),
                                  widths=(n, n * n, ny, ny * ny, 1, n * n), out=out)
        xf, Pf, e, S, ll, Phi = fields
        priors = accs[:-1]
        log_likelihood = check_likelihood(ll)
        mark_missing(e, seen)
        self.x, self.P = xf[-1].copy(), square_matrices(Pf[-1:], n)[0]
        return FilterResult(x_predicted=priors[:, :n], P_predicted=square_matrices(priors[:, n:], n), x_filtered=xf,
                            P_filtered=square_matrices(Pf, n), transition=square_matrices(Phi[:-1], n),
                            innovation=e, innovation_covariance=square_matrices(S, ny),
                            iterations=np.ones(N, dtype=int), log_likelihood=log_likelihood,
                            state_names=model.state_names, output_names=model.output_names, time=t.copy(),
                            buffers=(accs, fields))

    def smooth(self, data: Dataset):
        """The filter pass and its unscented RTS smoothing (the RTS recursion on the statistically
        linearised transitions: the gain ``C P(k+1|k)^-1`` of Sarkka's unscented RTS smoother).

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        FilterResult
        SmootherResult
        """
        result = self.filter(data)
        return result, rts_smoother(result)
