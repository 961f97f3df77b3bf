"""Parameters and signals of a model: names, bounds, nominal values, units, scales, and the
sampling priors (uniform, log-uniform, Gaussian truncated to the box) that decide where
stage 1 samples."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ModelError


__all__ = ["Uniform", "LogUniform", "Gaussian", "Parameter", "Signal", "LOG_SPAN"]

#: a finite box of one sign with ``ub / lb`` at least this (a decade) is sampled log-uniformly by default
LOG_SPAN = 10.0


# ----------------------------------------------------------------------------- priors
def _ndtr(x):
    from scipy import special  # scipy is imported on first use: `import casest` stays fast

    return special.ndtr(x)


def _ndtri(q):
    from scipy import special

    return special.ndtri(q)


@dataclass(frozen=True)
class Uniform:
    """Uniform sampling prior on the parameter's box ``[lb, ub]`` (both must be finite).

    It takes no parameters: the parameter's bounds are its support; it is the default prior
    of a parameter with a finite box.
    """

    def ppf(self, u: np.ndarray, lb: float, ub: float) -> np.ndarray:
        """Quantile function on ``[lb, ub]``; ``u`` in [0, 1], any shape.

        Parameters
        ----------
        u : ndarray
            Probabilities in [0, 1], any shape.
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        ndarray
            Parameter values, the shape of ``u``.
        """
        return lb + (ub - lb) * np.asarray(u, dtype=float)

    def cdf(self, x: np.ndarray, lb: float, ub: float) -> np.ndarray:
        """Inverse of :meth:`ppf`: position in [0, 1].

        Parameters
        ----------
        x : ndarray
            Parameter values, any shape.
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        ndarray
            Probabilities in [0, 1], the shape of ``x``.
        """
        return (np.asarray(x, dtype=float) - lb) / (ub - lb)

    def check(self, name: str, lb: float, ub: float) -> None:
        """Raise a :class:`ModelError` if the prior does not fit the parameter's bounds.

        Parameters
        ----------
        name : str
            The parameter, for the message.
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        None
        """
        if not (np.isfinite(lb) and np.isfinite(ub)):
            raise ModelError(
                f"parameter {name!r}: a Uniform prior needs finite bounds, got [{lb}, {ub}]; "
                "give lb and ub, or use Gaussian(mean, std)"
            )

    def centre(self, lb: float, ub: float) -> float:
        """The nominal value of a parameter declared without one: the middle of finite bounds, else the point of the box nearest 0.

        Parameters
        ----------
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        float
        """
        if np.isfinite(lb) and np.isfinite(ub):
            return 0.5 * (lb + ub)
        return float(min(max(0.0, lb), ub))

    def spread(self, lb: float, ub: float) -> float:
        """Typical magnitude of the parameter under the prior (its default scale).

        Parameters
        ----------
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        float
        """
        return (ub - lb) / math.sqrt(12.0)

    def finite_support(self, lb: float, ub: float) -> bool:
        """Whether the prior truncated to the bounds has finite support (a sweep needs it).

        Parameters
        ----------
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        bool
        """
        return True


@dataclass(frozen=True)
class LogUniform:
    """Log-uniform prior on ``[lb, ub]`` with ``0 < lb < ub`` (or ``lb < ub < 0``, mirrored).

    It takes no parameters: the parameter's bounds are its support, e.g.
    ``Parameter("k", lb=1e-3, ub=10.0, prior=LogUniform())``.
    """

    def check(self, name: str, lb: float, ub: float) -> None:
        """Raise a :class:`ModelError` if the prior does not fit the parameter's bounds.

        Parameters
        ----------
        name : str
            The parameter, for the message.
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        None
        """
        if not (np.isfinite(lb) and np.isfinite(ub)) or lb * ub <= 0 or lb == ub:
            raise ModelError(
                f"parameter {name!r}: a LogUniform prior needs finite bounds of one sign, "
                f"not containing 0, got [{lb}, {ub}]"
            )

    def ppf(self, u: np.ndarray, lb: float, ub: float) -> np.ndarray:
        """Quantile function of the prior truncated to ``[lb, ub]``.

        Parameters
        ----------
        u : ndarray
            Probabilities in [0, 1], any shape.
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        ndarray
            Parameter values, the shape of ``u``.
        """
        u = np.asarray(u, dtype=float)
        sign = 1.0 if lb > 0 else -1.0
        log_lb, log_ub = np.log(abs(lb)), np.log(abs(ub))
        return sign * np.exp(log_lb + (log_ub - log_lb) * u)

    def cdf(self, x: np.ndarray, lb: float, ub: float) -> np.ndarray:
        """Inverse of :meth:`ppf`: position in [0, 1].

        Parameters
        ----------
        x : ndarray
            Parameter values, any shape.
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        ndarray
            Probabilities in [0, 1], the shape of ``x``.
        """
        log_lb, log_ub = np.log(abs(lb)), np.log(abs(ub))
        return (np.log(np.abs(np.asarray(x, dtype=float))) - log_lb) / (log_ub - log_lb)

    def centre(self, lb: float, ub: float) -> float:
        """The nominal value of a parameter declared without one: the geometric mean of finite bounds of one sign, else as :class:`Uniform`.

        Parameters
        ----------
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        float
        """
        if np.isfinite(lb) and np.isfinite(ub) and lb * ub > 0:
            return float(math.copysign(math.sqrt(lb * ub), lb))
        return Uniform().centre(lb, ub)

    def spread(self, lb: float, ub: float) -> float:
        """Typical magnitude: the geometric mean of the bounds' magnitudes.

        Parameters
        ----------
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        float
        """
        return math.sqrt(abs(lb * ub))

    def finite_support(self, lb: float, ub: float) -> bool:
        """Whether the prior truncated to the bounds has finite support (a sweep needs it).

        Parameters
        ----------
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        bool
        """
        return True


@dataclass(frozen=True)
class Gaussian:
    """Gaussian prior N(mean, std**2), truncated to the parameter's box (paper Sec. III).

    Parameters
    ----------
    mean : float
        Mean, in the parameter's unit.
    std : float
        Standard deviation (> 0), in the parameter's unit.
    """

    mean: float = 0.0
    std: float = 1.0

    def check(self, name: str, lb: float, ub: float) -> None:
        """Raise a :class:`ModelError` if the prior does not fit the parameter's bounds.

        Parameters
        ----------
        name : str
            The parameter, for the message.
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        None
        """
        if not (np.isfinite(self.mean) and np.isfinite(self.std) and self.std > 0):
            raise ModelError(f"parameter {name!r}: Gaussian prior needs a finite mean and std > 0")
        cdf_lo, cdf_hi = self._cdf_box(lb, ub)
        if cdf_hi - cdf_lo < 1e-12:
            raise ModelError(
                f"parameter {name!r}: Gaussian({self.mean}, {self.std}) has no probability "
                f"mass inside the bounds [{lb}, {ub}]; move the mean or widen the bounds"
            )

    def _cdf_box(self, lb: float, ub: float) -> tuple[float, float]:
        lo = _ndtr((lb - self.mean) / self.std) if np.isfinite(lb) else 0.0
        hi = _ndtr((ub - self.mean) / self.std) if np.isfinite(ub) else 1.0
        return float(lo), float(hi)

    def cdf(self, x: np.ndarray, lb: float, ub: float) -> np.ndarray:
        """Inverse of :meth:`ppf`: position in [0, 1] of the truncated distribution.

        Parameters
        ----------
        x : ndarray
            Parameter values, any shape.
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        ndarray
            Probabilities in [0, 1], the shape of ``x``.
        """
        lo, hi = self._cdf_box(lb, ub)
        return (_ndtr((np.asarray(x, dtype=float) - self.mean) / self.std) - lo) / (hi - lo)

    def ppf(self, u: np.ndarray, lb: float, ub: float) -> np.ndarray:
        """Quantile function of the prior truncated to ``[lb, ub]``.

        Parameters
        ----------
        u : ndarray
            Probabilities in [0, 1], any shape.
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        ndarray
            Parameter values, the shape of ``u``.
        """
        lo, hi = self._cdf_box(lb, ub)
        q = lo + (hi - lo) * np.asarray(u, dtype=float)
        values = self.mean + self.std * _ndtri(np.clip(q, 1e-300, 1 - 1e-16))
        return np.clip(values, lb, ub)

    def centre(self, lb: float, ub: float) -> float:
        """The nominal value of a parameter declared without one: the mean, held inside the bounds.

        Parameters
        ----------
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        float
        """
        return float(min(max(self.mean, lb), ub))

    def spread(self, lb: float, ub: float) -> float:
        """Typical magnitude of the parameter under the prior (its default scale).

        Parameters
        ----------
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        float
        """
        return self.std

    def finite_support(self, lb: float, ub: float) -> bool:
        """Whether the prior truncated to the bounds has finite support (a sweep needs it).

        Parameters
        ----------
        lb, ub : float
            The parameter's bounds.

        Returns
        -------
        bool
        """
        return bool(np.isfinite(lb) and np.isfinite(ub))


# ----------------------------------------------------------------------------- declarations
def _is_real(value) -> bool:
    """A real number (Python or NumPy), not a bool."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


@dataclass(frozen=True)
class Parameter:
    """An unknown static parameter (an element of xi).

    Parameters
    ----------
    name : str
        Name of the CasADi symbol that stands for it in the model's outputs.
    lb, ub : float
        Box constraint, physical unit (``-inf``/``inf`` for none).
    nominal : float, optional
        Prior best guess; used as a start where stage 1 gives none. Default: the mean of
        a Gaussian prior, the geometric mean of a log-uniform box, the midpoint of a
        finite box, else 0 (moved into a half-open box).
    prior : Uniform, LogUniform or Gaussian, optional
        Distribution from which stage 1 draws candidates (truncated to ``[lb, ub]``).
        Default: ``LogUniform()`` when both bounds are finite, of one sign and ``ub / lb`` is at
        least :data:`LOG_SPAN` (a decade: uniform draws over such a box would leave its lower
        decades almost unsampled), ``Uniform()`` for any other finite box, otherwise
        ``Gaussian(nominal, max(1, |nominal|))``. The NLP's scale (``scale``) of a finite box
        comes from its uniform spread either way.
    unit : str
        Unit label for reports and CSV headers.
    scale : float, optional
        Typical magnitude; the NLP works with ``theta / scale``. Default from the prior.
    fixed : bool
        Hold the parameter at ``nominal`` instead of estimating it (it drops out of every
        stage; see ``casest.estimate(fixed=...)`` to fix values without editing the model).
    """

    name: str
    lb: float = -math.inf
    ub: float = math.inf
    nominal: float | None = None
    prior: Uniform | LogUniform | Gaussian | None = None
    unit: str = ""
    scale: float | None = None
    fixed: bool = False

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ModelError(f"a parameter name must be a non-empty string, got {self.name!r}")
        if self.nominal is None:
            object.__setattr__(self, "nominal", self._default_nominal())
        for field_name, label, no_bound in (("lb", "lower bound", "-inf"), ("ub", "upper bound", "inf"),
                                            ("nominal", "nominal value", None)):
            self._check_number(field_name, label, no_bound)
        if math.isinf(self.nominal):
            raise ModelError(f"parameter {self.name!r}: nominal value {self.nominal} must be finite")

    def _check_number(self, field_name: str, label: str, no_bound: str | None) -> None:
        """Refuse a field that is not a real number (a string, a bool) or is NaN, saying what to write."""
        value = getattr(self, field_name)
        if not _is_real(value):
            hint = f"; write {field_name}=float({value!r})" if isinstance(value, str) else ""
            raise ModelError(f"parameter {self.name!r}: {label} {value!r} is a {type(value).__name__}, not a number"
                             + hint)
        if math.isnan(value):
            hint = f"; use {no_bound} for no bound" if no_bound else "; give a finite value inside the bounds"
            raise ModelError(f"parameter {self.name!r}: {label} is NaN" + hint)

    def _default_nominal(self):
        """The nominal value of a declaration without one (see ``nominal``); bad bounds pass through."""
        lb, ub = self.lb, self.ub
        if not (_is_real(lb) and _is_real(ub)) or math.isnan(lb) or math.isnan(ub):
            return 0.0  # the bound checks below name the problem
        return (self.prior or Uniform()).centre(lb, ub)

    @property
    def sampling_prior(self) -> Uniform | LogUniform | Gaussian:
        """The prior used for sampling, with the documented default filled in."""
        if self.prior is not None:
            return self.prior
        if np.isfinite(self.lb) and np.isfinite(self.ub):
            # a box of one sign over more than a decade: uniform draws would leave its lower decades unsampled
            return LogUniform() if self.lb * self.ub > 0 and max(self.lb / self.ub, self.ub / self.lb) >= LOG_SPAN else Uniform()
        return Gaussian(self.nominal, max(1.0, abs(self.nominal)))

    @property
    def declared_prior(self) -> Uniform | LogUniform | Gaussian:
        """The prior as declared, a finite box's default uniform whatever its span (the NLP's scale
        and the exchangeability of two parameters read it; :attr:`sampling_prior` is what stage 1
        draws from)."""
        if self.prior is None and np.isfinite(self.lb) and np.isfinite(self.ub):
            return Uniform()
        return self.sampling_prior

    @property
    def typical_scale(self) -> float:
        """Magnitude used to scale the NLP unknown (user ``scale``, else prior spread)."""
        if self.scale is not None:
            return float(self.scale)
        spread = self.declared_prior.spread(self.lb, self.ub)
        # a box wider than any magnitude the data could pin down (+-1e300) says no more than no box
        return float(max(spread, abs(self.nominal), 1e-8)) if np.isfinite(spread) and spread < 1e100 else 1.0


@dataclass(frozen=True)
class Signal:
    """A known per-sample quantity (a state x_k or an input u_k).

    Parameters
    ----------
    name : str
        Name of the CasADi symbol and of the data column.
    unit : str
        Unit label.
    """

    name: str
    unit: str = ""
