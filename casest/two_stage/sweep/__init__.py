"""Stage 1: the residual-sampling sweep of xi2 with a linear least squares for xi1 at every
candidate (paper Sec. II.C), its landscape and verdict.

Modules: :mod:`.settings` (SweepSettings, the verdicts), :mod:`.candidates` (where xi2 is
sampled), :mod:`.gram_program` (what is built from A and b alone, once per model),
:mod:`.evaluators` (A(xi2), b(xi2) and the Gram sums over the data),
:mod:`.least_squares` (batched and box-constrained solves), :mod:`.analysis` (minima and the
paper's validity conditions), :mod:`.error_bound` (the paper's E and bracket, Eq. 7-13), :mod:`.landscape` (the result),
:mod:`.orchestration` (:func:`sweep`, which runs them in order), :mod:`.streamed` (designs
larger than memory: tasks that generate, rank and store their own candidates) and
:mod:`.confidence` (likelihood-ratio sets of xi2 from the sweep).
"""

from ...errors import IdentifiabilityError
from ...problem.measurement import check_predictions
from .candidates import draw_candidates
from .error_bound import BRACKET_SIDES, ErrorBound, paper_error_bound
from .landscape import Landscape
from ...backend.least_squares import batched_least_squares, box_least_squares
from .orchestration import sweep
from .settings import VERDICTS, SweepSettings
from .streamed import StreamedSweep, design_size, streamed_sweep, task_candidates
from .confidence import LikelihoodRatioSet, ParameterInterval, confidence_sets, likelihood_ratio_set, refine_intervals


__all__ = ["sweep", "SweepSettings", "Landscape", "IdentifiabilityError", "draw_candidates", "VERDICTS",
           "batched_least_squares", "box_least_squares", "check_predictions", "ErrorBound", "paper_error_bound",
           "BRACKET_SIDES", "streamed_sweep", "StreamedSweep", "task_candidates", "design_size",
           "confidence_sets", "likelihood_ratio_set", "refine_intervals", "LikelihoodRatioSet", "ParameterInterval"]
