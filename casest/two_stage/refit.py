"""``casest.refit``: estimate a model again with the change its estimate's diagnosis names."""

from __future__ import annotations

from ..errors import OptionError
from ..estimation.refit import REFITTERS, Refit, refit_with
from .pipeline import estimate

__all__ = ["refit"]


def refit(result, model, data, **options) -> Refit:
    """Estimate ``model`` again with the change ``result.diagnosis`` names (a time shift of a
    signal, a bias, a scale, a step or a missing term; :mod:`casest.estimation.refit`).

    Parameters
    ----------
    result : Estimate, Regression or FrequencyEstimate
        An estimate whose conclusion is a model error with a diagnosis (a frequency-domain
        estimate is estimated again in the frequency domain with the diagnosed delay).
    model : Model or DynamicModel
        The model estimated.
    data : Dataset
        Its record.
    **options
        Passed to :func:`casest.estimate` (without them the refit starts from the estimate and
        the diagnosed change: a local solve), or to the result type's own refit
        (:data:`casest.estimation.refit.REFITTERS`).

    Returns
    -------
    Refit
        The new estimate, the change's parameter with its std, and each output's residual rms
        before and after.

    Raises
    ------
    OptionError
        The estimate has no diagnosis.
    """
    own = REFITTERS.get(type(result))
    if own is not None:
        return own(result, model, data, **options)
    diagnosis = getattr(result, "diagnosis", None)
    if diagnosis is None:
        raise OptionError("this estimate has no diagnosis: its residuals depend on nothing, or no candidate change "
                          "explains them (see its conclusion)")
    if options:
        return refit_with(diagnosis, model, data, estimate, first=result, **options)
    return refit_with(diagnosis, model, data, estimate, first_theta=result.theta)
