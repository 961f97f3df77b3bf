"""``casest.refit`` of a frequency-domain estimate: the diagnosed delay estimated as a parameter."""

from __future__ import annotations

import numpy as np

from ..errors import OptionError
from ..estimation.refit import Refit, delay_name, register_refitter
from .domain import frequency_domain_estimate
from .result import FrequencyEstimate

__all__ = ["refit_delay"]


@register_refitter(FrequencyEstimate)
def refit_delay(estimate: FrequencyEstimate, model, data, states=None, settings=None) -> Refit:
    """Estimate the model again in the frequency domain with the diagnosed delay as a parameter,
    started at the diagnosed value (``casest.refit`` calls it for a :class:`FrequencyEstimate`).

    Parameters
    ----------
    estimate : FrequencyEstimate
        An estimate with a diagnosis.
    model : DynamicModel
        The model estimated.
    data : Dataset
        Its record.
    states : mapping, optional
        Equation error: which output is each state (as for the first estimate).
    settings : SolverSettings, optional

    Returns
    -------
    Refit
        The new estimate, the delay and its std in samples, each channel's residual rms
        (``sqrt(S_j)``) before and after.

    Raises
    ------
    OptionError
        The estimate has no diagnosis.
    """
    diagnosis = estimate.diagnosis
    if diagnosis is None:
        raise OptionError("this estimate has no diagnosis: its residuals are coherent with no input, or no delay "
                          "explains them (see its conclusion)")
    dt = float(estimate.sample_interval)
    bound = np.pi / float(np.max(estimate.frequencies))
    start = float(np.clip(diagnosis.value * dt, -0.99 * bound, 0.99 * bound))
    new = frequency_domain_estimate(model, data, estimate.frequencies, method=estimate.method, states=states,
                                    settings=settings, delay=diagnosis.signals, delay_start=start)
    index = list(new.parameter_names).index(delay_name(diagnosis.signals))
    return Refit(new, new.parameter_names[index], float(new.theta[index]) / dt, float(new.std[index]) / dt,
                 np.sqrt(np.asarray(estimate.spectra, dtype=float)), np.sqrt(np.asarray(new.spectra, dtype=float)))
