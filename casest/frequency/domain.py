"""Frequency-domain estimation (Klein and Morelli, *Aircraft System Identification*, Ch. 7):
equation error and output error on the finite Fourier transforms of a record over a chosen band,
for linear(ised) :class:`casest.DynamicModel` s, and the recursive Fourier transform for online use.

The model is linearised about its initial state and the record's first input (exact for linear
models): ``A = df/dx``, ``B = df/du``, ``C = dh/dx``, ``D = dh/du``, functions of theta. With
``X(w) = sum_k x(t_k) exp(-j w t_k) dt`` the finite Fourier transform at the chosen frequencies:

- **output error** fits ``Y(w) = (C (jw I - A)^-1 B + D) U(w)``, the measured outputs' transform
  against the model's transfer function (the record must start and end near rest, or the
  transient's ends enter as error);
- **equation error** fits ``jw X(w) = A X(w) + B U(w)``, with the states measured (outputs named
  like the states, or ``states=``).

Both minimise ``sum_w sum_j |v_j(w)|^2 / S_j`` with the residual spectra ``S_j`` re-estimated as
their mean square until they settle (the frequency-domain analogue of output error's R), by
IPOPT with the exact Hessian inside the parameters' bounds; the covariance is the inverse of
``2 Re sum_w J^H S^-1 J`` (the residuals' real and imaginary parts each carry half of S: on 30
simulated short-period records its std were 0.81-1.23 of the Monte-Carlo spread). The transforms
at frequencies ``2 pi k / T`` (T the record's length) are independent; closer ones are not, and
their std come out too small (a note says so). Parameters that act only at zero
frequency (an output bias) drop out: they are held at their nominal values and named.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings, active_bounds, run_ipopt
from ..checks import finite_array
from ..data.dataset import Dataset
from ..errors import DataError, OptionError
from ..models.dynamic import DynamicModel
from ..problem.problem import Problem
from ..status import Note, NoteCode
from ..estimation.result_protocol import PlainResult, conclusion_of, register_record
from ..estimation.uncertainty import covariance_from_hessian
from ..options import FrequencyMethod

__all__ = ["fourier_transform", "RecursiveFourierTransform", "FrequencyEstimate", "frequency_domain_estimate"]

#: reweighting rounds (residual spectra re-estimated) before the estimate is reported as not settled
MAX_ROUNDS = 20


def fourier_transform(values, time, frequencies) -> np.ndarray:
    """The finite Fourier transform ``X(w) = sum_k x(t_k) exp(-j w t_k) dt_k`` at chosen frequencies.

    Parameters
    ----------
    values : array_like, shape (N,) or (N, channels)
    time : array_like, shape (N,)
        Sample times (s); ``dt_k`` is the interval to the next sample (the last repeats).
    frequencies : array_like, shape (F,)
        Angular frequencies (rad/s).

    Returns
    -------
    ndarray, complex, shape (F,) or (F, channels)
    """
    x = np.asarray(values, dtype=float)
    t = np.asarray(time, dtype=float).reshape(-1)
    w = np.asarray(frequencies, dtype=float).reshape(-1)
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2] if t.size > 1 else 1.0))
    kernel = np.exp(-1j * np.outer(w, t)) * dt  # (F, N)
    return kernel @ x


class RecursiveFourierTransform:
    """The finite Fourier transform updated sample by sample, for online estimation: after each
    sample the transform of the record so far (one complex multiply-add per frequency and channel).

    Parameters
    ----------
    frequencies : array_like, shape (F,)
        Angular frequencies (rad/s).
    dt : float
        Sample interval (s).
    channels : int
    """

    def __init__(self, frequencies, dt: float, channels: int = 1):
        self.frequencies = finite_array(frequencies, "frequencies", shape=(None,), error=OptionError)
        self.dt = float(dt)
        if not self.dt > 0:
            raise OptionError(f"dt must be a positive number of seconds, got {dt!r}")
        self._rotation = np.exp(-1j * self.frequencies * self.dt)
        self._phase = np.ones_like(self._rotation)
        self.transform = np.zeros((self.frequencies.size, int(channels)), dtype=complex)
        self.n_samples = 0

    def update(self, sample) -> np.ndarray:
        """Add one sample (at time ``n_samples * dt``).

        Parameters
        ----------
        sample : array_like, shape (channels,)

        Returns
        -------
        ndarray, complex, shape (F, channels)
            The transform so far.
        """
        x = np.asarray(sample, dtype=float).reshape(-1)
        self.transform += np.outer(self._phase, x) * self.dt
        self._phase *= self._rotation
        self.n_samples += 1
        return self.transform


@register_record
@dataclass(frozen=True)
class FrequencyEstimate(PlainResult):
    """A frequency-domain estimate, a member of casest's result protocol
    (:class:`~casest.estimation.result_protocol.EstimateLike`).

    Attributes
    ----------
    method : str
        ``"output-error"`` or ``"equation-error"``.
    parameter_names : tuple of str
    theta : ndarray, shape (n_parameters,)
        Every parameter (the held ones at their nominal values).
    std : ndarray, shape (n_parameters,)
        NaN for the held ones.
    held : tuple of str
        Parameters that do not act at the chosen frequencies (biases), held at their nominals.
    frequencies : ndarray, shape (F,)
        Angular frequencies (rad/s).
    spectra : ndarray, shape (channels,)
        The residual spectra S_j at the estimate.
    success : bool
    notes : tuple of Note
        Each a ``str`` with its :class:`~casest.status.NoteCode` in ``.code``.
    covariance : ndarray, shape (n_parameters, n_parameters), or None
        The inverse information of the parameters acting in the band (NaN rows and columns for
        the held ones).
    """

    FORMAT = "casest.FrequencyEstimate/1"

    method: str
    parameter_names: tuple
    theta: np.ndarray
    std: np.ndarray
    held: tuple
    frequencies: np.ndarray
    spectra: np.ndarray
    success: bool
    notes: tuple
    covariance: np.ndarray | None = None

    @property
    def status(self) -> str:
        """``"Solve_Succeeded"``, or ``"Not_Converged"`` (the notes say why)."""
        return "Solve_Succeeded" if self.success else "Not_Converged"

    def conclusion(self) -> tuple:
        """``LOCAL`` when the reweighted solve converged and every acting parameter has a std (the
        held ones are named in the notes), else ``CAUTION`` with what failed.

        Returns
        -------
        TrustCode
        str
        """
        acting = _ActingView(self)
        return conclusion_of(acting, f"the frequency-domain {self.method} converged over {self.frequencies.size} "
                                     "frequencies")

    def report(self) -> str:
        """Text report in fixed sections; ``+/-`` is one standard deviation.

        Returns
        -------
        str
        """
        w = self.frequencies
        lines = [f"[[Model]] frequency-domain {self.method} (Klein and Morelli Ch. 7)", "[[Fit Statistics]]",
                 f"    success            = {self.success} ({self.status})",
                 f"    frequencies        = {w.size} from {w.min():.4g} to {w.max():.4g} rad/s",
                 "[[Parameters]] (value +/- one standard deviation)"]
        for name, value, std in zip(self.parameter_names, self.theta, self.std):
            held = " (held: does not act in the band)" if name in self.held else ""
            lines.append(f"    {name} = {value:.8g}" + (f" +/- {std:.4g}" if np.isfinite(std) else "") + held)
        lines.append("[[Residual spectra]] (per channel)")
        lines += [f"    S[{j}] = {s:.6g}" for j, s in enumerate(self.spectra)]
        if self.notes:
            lines.append("[[Notes]]")
            lines += [f"    - {n}" for n in self.notes]
        code, reason = self.conclusion()
        lines.append(f"[[Conclusion]] {code.value.upper()}: {reason}")
        return "\n".join(lines)

    def as_dict(self) -> dict:
        """``{name: (value, std)}``.

        Returns
        -------
        dict
        """
        return {n: (float(v), float(s)) for n, v, s in zip(self.parameter_names, self.theta, self.std)}


class _ActingView:
    """A frequency estimate seen through its acting parameters (the held ones have no std by design)."""

    def __init__(self, estimate: FrequencyEstimate):
        keep = [i for i, n in enumerate(estimate.parameter_names) if n not in estimate.held]
        self.parameter_names = tuple(estimate.parameter_names[i] for i in keep)
        self.std = np.asarray(estimate.std)[keep]
        self.success, self.status, self.notes = estimate.success, estimate.status, estimate.notes


def _linearisation(model: DynamicModel, data: Dataset):
    """``(A, B, C, D)`` as an SX function of theta, at the initial state and first input."""
    n, nu = model.n_states, len(model.inputs)
    x, u, theta = ca.SX.sym("x", n), ca.SX.sym("u", nu), ca.SX.sym("theta", model.n_parameters)
    f = model.rhs_function(x, u, theta)
    h = model.output_model.function(ca.vertcat(x, u), theta)
    x0 = np.asarray(model.initial_function(model.nominal, model.initial_values(data))).reshape(-1)
    u0 = data.signals[0, 1:] if nu else np.zeros(0)
    fun = ca.Function("ABCD", [x, u, theta], [ca.jacobian(f, x), ca.jacobian(f, u), ca.jacobian(h, x),
                                              ca.jacobian(h, u)])
    return [ca.substitute(M, ca.vertcat(x, u), ca.vertcat(ca.DM(x0), ca.DM(u0))) for M in fun(x, u, theta)], theta


def _state_columns(model: DynamicModel, states) -> list:
    names = list(model.output_names)
    mapping = dict(states) if states is not None else {s: s for s in model.state_names if s in names}
    _check_state_mapping(model, mapping)
    return [names.index(mapping[s]) for s in model.state_names]


def _check_state_mapping(model: DynamicModel, mapping: dict) -> None:
    """Every state named, each to an output the model has."""
    names = list(model.output_names)
    missing = [s for s in model.state_names if s not in mapping]
    if missing:
        raise OptionError(f"equation error needs every state measured: give states={{state: output column}} for "
                          f"{missing} (outputs: {names})")
    unknown = [c for c in mapping.values() if c not in names]
    if unknown:
        raise OptionError(f"states= names outputs {unknown}, which the model does not have ({names})")


def _residuals(method: str, ABCD, w: np.ndarray, U: np.ndarray, Y: np.ndarray, X) -> list:
    """Real and imaginary parts of the residual of each channel, stacked over frequencies (SX)."""
    A, B, C, D = ABCD
    n = A.size1()
    out_r, out_i = [], []
    for k, wk in enumerate(w):
        Ur, Ui = ca.DM(U[k].real), ca.DM(U[k].imag)
        if method == "output-error":
            # (jw I - A)(Xr + j Xi) = B U, as a real system of twice the size
            M = ca.vertcat(ca.horzcat(-A, -wk * ca.DM.eye(n)), ca.horzcat(wk * ca.DM.eye(n), -A))
            Z = ca.solve(M, ca.vertcat(ca.mtimes(B, Ur), ca.mtimes(B, Ui)))
            Xr, Xi = Z[:n], Z[n:]
            model_r, model_i = ca.mtimes(C, Xr) + ca.mtimes(D, Ur), ca.mtimes(C, Xi) + ca.mtimes(D, Ui)
            out_r.append(ca.DM(Y[k].real) - model_r)
            out_i.append(ca.DM(Y[k].imag) - model_i)
        else:
            Xr, Xi = ca.DM(X[k].real), ca.DM(X[k].imag)
            rhs_r, rhs_i = ca.mtimes(A, Xr) + ca.mtimes(B, Ur), ca.mtimes(A, Xi) + ca.mtimes(B, Ui)
            out_r.append(-wk * Xi - rhs_r)  # jw X = -w Xi + j w Xr
            out_i.append(wk * Xr - rhs_i)
    return [ca.horzcat(*out_r), ca.horzcat(*out_i)]  # channels x F each


def frequency_domain_estimate(model: DynamicModel | Problem, data: Dataset | None, frequencies: Sequence[float],
                              method: FrequencyMethod = "output-error", states: Mapping | None = None,
                              settings: SolverSettings | None = None) -> FrequencyEstimate:
    """Estimate a linear(ised) dynamic model's parameters in the frequency domain.

    Parameters
    ----------
    model : DynamicModel or Problem
        A :class:`casest.Problem` (with ``data`` None) brings its record and its fixed
        parameters (its noise model unknown and diagonal: the method weights each channel by
        its own residual spectrum).
    data : Dataset or None
        The model's record (time, inputs, outputs), without missing samples.
    frequencies : sequence of float
        Angular frequencies (rad/s) of the band, all positive (a plain DFT at each).
    method : {"output-error", "equation-error"}
        See the module docstring.
    states : mapping of state name to output name, optional
        Equation error: which measured output is each state (default: outputs named like the states).
    settings : SolverSettings, optional
        IPOPT's settings for each reweighted solve (default: casest's, with ``tol=1e-12``).

    Returns
    -------
    FrequencyEstimate

    Raises
    ------
    OptionError
        Not a DynamicModel, an unknown method, frequencies that are not positive, states not measured.
    DataError
        Missing samples.
    """
    if isinstance(model, Problem):
        model, data = _problem_parts(model, data)
    if not isinstance(model, DynamicModel):
        raise OptionError("frequency_domain_estimate needs a casest.DynamicModel (states, rhs, outputs)")
    if settings is not None and not isinstance(settings, SolverSettings):
        raise OptionError(f"settings must be a casest.SolverSettings (or left out), got {type(settings).__name__}")
    if method not in ("output-error", "equation-error"):
        raise OptionError(f"method must be 'output-error' or 'equation-error', got {method!r}")
    w = finite_array(frequencies, "frequencies", shape=(None,), error=OptionError)
    if w.size == 0:
        raise OptionError("frequencies is empty: give the band's angular frequencies (rad/s), e.g. "
                          "numpy.linspace(0.5, 10.0, 40)")
    if np.any(w <= 0):
        raise OptionError("frequencies must be positive angular frequencies (rad/s): zero frequency carries the "
                          "biases and trim, which the frequency domain leaves out")
    model.check_data(data)
    if not np.all(np.isfinite(data.outputs)):
        raise DataError("the frequency domain needs every sample of every output; fill or cut the missing ones")
    t, U_t = data.signals[:, 0], data.signals[:, 1:]
    _check_band(w, t)
    U = fourier_transform(U_t, t, w).reshape(w.size, -1)
    Y = fourier_transform(data.outputs, t, w).reshape(w.size, -1)
    X = Y[:, _state_columns(model, states)] if method == "equation-error" else None
    ABCD, theta = _linearisation(model, data)
    acting = [i for i in range(model.n_parameters)
              if any(ca.depends_on(M, theta[i]) for M in (ABCD if method == "output-error" else ABCD[:2]))]
    held = tuple(model.parameter_names[i] for i in range(model.n_parameters) if i not in acting)
    channels = len(_state_columns(model, states)) if method == "equation-error" else model.n_outputs
    unknowns = len(acting) + channels  # the parameters and each channel's residual spectrum
    if 2 * w.size * channels <= unknowns:
        raise OptionError(f"{w.size} frequencies give {2 * w.size * channels} real residuals for {len(acting)} "
                          f"parameters and {channels} residual spectra: give more than {unknowns // (2 * channels)} "
                          "frequencies across the band the record excites")
    estimate = _solve(model, method, w, _residuals(method, ABCD, w, U, Y, X), theta, acting, held,
                      settings or SolverSettings(tol=1e-12))
    if _nonlinear(model):
        note = Note("the model is nonlinear: the frequency domain fits its linearisation about the initial state "
                    "and the first input, which a manoeuvre away from that point does not follow; check the estimate "
                    "by output error in the time domain (casest.estimate)", NoteCode.FREQUENCIES)
        estimate = FrequencyEstimate(**{**estimate.__dict__, "notes": estimate.notes + (note,)})
    resolution = 2 * np.pi / (t[-1] - t[0] + (t[1] - t[0]))
    if w.size > 1 and np.min(np.diff(np.sort(w))) < 0.999 * resolution:
        note = Note(f"frequencies closer than the record's resolution 2 pi / T = {resolution:.4g} rad/s have "
                    "correlated transforms: the std are too small; space them by at least that", NoteCode.FREQUENCIES)
        estimate = FrequencyEstimate(**{**estimate.__dict__, "notes": estimate.notes + (note,)})
    return estimate


def _check_band(w: np.ndarray, t: np.ndarray) -> None:
    """Refuse frequencies at or above the record's Nyquist frequency (their transforms alias)."""
    dt = float(np.median(np.diff(t))) if t.size > 1 else np.inf
    nyquist = np.pi / dt
    above = w[w >= nyquist]
    if above.size:
        raise OptionError(f"{above.size} of the frequencies reach or pass the record's Nyquist frequency pi / dt = "
                          f"{nyquist:.4g} rad/s (the highest {float(w.max()):.4g}): their transforms alias lower "
                          "frequencies; keep the band below it, where the inputs excite the model")


def _nonlinear(model: DynamicModel) -> bool:
    """Whether the model's rhs or outputs depend on the states or inputs other than linearly."""
    x, u = model.rhs_function.sx_in(0), model.rhs_function.sx_in(1)
    theta = model.rhs_function.sx_in(2)
    z = ca.vertcat(x, u)
    rhs = model.rhs_function(x, u, theta)
    out = model.output_model.function(z, theta)
    return any(ca.depends_on(ca.jacobian(e, z), z) for e in (rhs, out))


def _solve(model, method, w, residual_parts, theta, acting, held, settings: SolverSettings) -> FrequencyEstimate:
    """Reweighted least squares of the residual spectra by IPOPT, and the Gauss-Newton covariance."""
    rr, ri = residual_parts
    free = ca.vertcat(*[theta[i] for i in acting])
    nominal = np.asarray(model.nominal, dtype=float)
    fixed_values = {theta[i]: nominal[i] for i in range(model.n_parameters) if i not in acting}
    if fixed_values:
        rr, ri = (ca.substitute(part, ca.vertcat(*fixed_values), ca.DM(list(fixed_values.values())))
                  for part in (rr, ri))
    channels = rr.size1()
    weights = ca.SX.sym("weights", channels)
    cost = 0.5 * ca.sum1(ca.sum2((rr**2 + ri**2) * ca.repmat(weights, 1, rr.size2())))
    scale = np.array([model.scales[i] for i in acting])
    s = ca.SX.sym("s", len(acting))
    scaled = ca.substitute(cost, free, s * ca.DM(scale))
    solver = ca.nlpsol("frequency_domain", "ipopt", {"x": s, "p": weights, "f": scaled}, settings.nlpsol_options())
    spectra_fn = ca.Function("spectra", [free], [ca.sum2(rr**2 + ri**2) / rr.size2()])
    lb = np.array([model.lower_bounds[i] for i in acting]) / scale
    ub = np.array([model.upper_bounds[i] for i in acting]) / scale
    x = np.clip(nominal[acting] / scale, lb, ub)
    S = np.asarray(spectra_fn(x * scale)).reshape(-1)
    notes, run = [], None
    for _ in range(MAX_ROUNDS):
        run = run_ipopt(solver, x0=x, lbx=lb, ubx=ub, p=1.0 / S)
        x = np.asarray(run.x, dtype=float).reshape(-1)
        S_new = np.maximum(np.asarray(spectra_fn(x * scale)).reshape(-1), 1e-300)
        settled = np.all(np.abs(S_new - S) <= 1e-9 * S_new)
        S = S_new
        if settled:
            break
    else:
        notes.append(Note(f"the residual spectra did not settle in {MAX_ROUNDS} rounds", NoteCode.NOT_VERIFIED))
    values = nominal.copy()
    values[acting] = x * scale
    std = np.full(model.n_parameters, np.nan)
    J = ca.Function("J", [free], [rr, ri, ca.jacobian(ca.vec(rr), free), ca.jacobian(ca.vec(ri), free)])
    vr, vi, Jr, Ji = (np.asarray(M) for M in J(values[acting]))
    per_row = np.tile(1.0 / S, rr.size2())  # vec is column-major: channels vary fastest
    gauss_newton = Jr.T @ (per_row[:, None] * Jr) + Ji.T @ (per_row[:, None] * Ji)
    gradient = Jr.T @ (per_row * vr.reshape(-1, order="F")) + Ji.T @ (per_row * vi.reshape(-1, order="F"))
    inside = np.array([side is None for side in active_bounds(x * scale, lb * scale, ub * scale, scale, tol=1e-9)],
                      dtype=bool)
    # converged: the Gauss-Newton step on the parameters off their bounds would lower the cost by
    # less than 1e-10 (IPOPT's own status can stop at rounding level on these linear-looking sums)
    try:
        decrement = float(gradient[inside] @ np.linalg.solve(gauss_newton[np.ix_(inside, inside)], gradient[inside]))
    except np.linalg.LinAlgError:
        decrement = np.inf
    success = bool(decrement <= 1e-10)
    if not success:
        notes.append(Note(f"not converged: the Gauss-Newton decrement is {decrement:.3g} ({run.status})",
                          NoteCode.NOT_VERIFIED))
    # circular complex residuals: real and imaginary parts each carry half of S
    covariance, null = covariance_from_hessian(2.0 * gauss_newton)
    full = np.full((model.n_parameters, model.n_parameters), np.nan)
    if null.shape[1] or not np.all(np.isfinite(covariance)):
        notes.append(Note("the information matrix is singular: some parameters are not identifiable in this band",
                          NoteCode.NOT_IDENTIFIABLE))
    else:
        std[acting] = np.sqrt(np.diag(covariance))
        full[np.ix_(acting, acting)] = covariance
    if held:
        notes.append(Note(f"{list(held)} do not act at nonzero frequencies (biases, trim): held at their nominal "
                          "values", NoteCode.FIXED))
    return FrequencyEstimate(method, tuple(model.parameter_names), values, std, held, w, S, success, tuple(notes),
                             covariance=full)


def _problem_parts(problem: Problem, data) -> tuple:
    """The model (fixed parameters substituted) and the one record of a Problem."""
    if data is not None or problem.experiments or problem.stage1_data is not None:
        raise OptionError("frequency_domain_estimate(problem, None, frequencies) takes the problem's one record: give "
                          "the data to the Problem (one Dataset, no experiments or stage-1 data), not here")
    if not problem.noise.estimated or not problem.noise.profiled_per_channel:
        raise OptionError(f"the frequency domain weights each channel by its own residual spectrum; this problem has "
                          f"{problem.describe_noise()}: use the default DiagonalNoise()")
    return problem.model, problem.data
