"""Stage-1 settings and the verdicts a sweep can give."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...models import OptionError
from ...options import ErrorBoundChoice, SweepCriterion, SweepDesign, SweepMethod, ValidityChecks, check_option


__all__ = ["VERDICTS", "SweepSettings"]


#: Verdicts of the sweep and what each one means.
VERDICTS = {
    "linear": "xi2 is empty: stage 1 is one linear least squares",
    "unique": "one clear minimum of Tr[R]; casest's linearisation and curvature checks (its forms of Eq. 17-18) hold",
    "multiple": "separate basins with statistically equivalent fits",
    "flat": "the curvature check (Eq. 18) fails: xi2 poorly determined around the best candidate",
    "coarse": "the linearisation check (Eq. 17) fails even after local refinement: the sweep is too coarse",
    "unresolved": "Eq. 17 holds at the best candidate but fails at further local minima: the sweep does not resolve "
                  "the landscape away from the best, where a deeper minimum may lie between the candidates",
}


@dataclass(frozen=True)
class SweepSettings:
    """Settings of the stage-1 sweep.

    Attributes
    ----------
    design : {"auto", "grid", "sobol", "random"}
        How xi2 candidates are drawn from the parameters' priors (truncated to their
        bounds). ``grid`` takes prior quantiles on a tensor grid; ``sobol`` a scrambled
        Sobol sequence; ``random`` independent draws. ``auto`` is a grid for up to two
        swept parameters and Sobol above.
    n_candidates : int
        Target number of candidates (a grid takes the largest full grid not above it).
    seed : int
        Seed of the Sobol scrambling and random draws.
    linearization_tol : float
        tau_1 of Eq. 17: largest accepted relative change of the prediction over half a
        sweep step.
    curvature_tol : float
        tau_2 of Eq. 18: smallest accepted eigenvalue of the normalised profile
        Gauss-Newton matrix in xi2.
    flat_spread : float
        Absolute flatness test (works for any number of swept parameters): the landscape
        is ``flat`` when the one-sigma interval of the worst-determined combination of xi2
        (profile Fisher information with R of the best candidate) spans more than this
        fraction of the swept prior mass (prior-CDF units).
    max_refinements : int
        When Eq. 17 fails at the best candidate, the sweep is refined around it (a local
        grid of half the step, ``3**n2`` points for up to four swept parameters, the
        ``2 n2`` axis neighbours above) up to this many times, until Eq. 17 holds; the
        verdict is ``coarse`` only if it still fails.
    confidence : float
        Level of the likelihood-ratio tests that decide whether another local minimum
        fits as well as the best one and whether a ridge separates them.
    memory_mb : float
        Memory budget for one chunk of candidates in ``method="qr"`` (A, b and the QR
        work arrays).
    method : {"gram", "qr"}
        ``gram`` (default): per-channel Gram matrices of [A, z - b] summed over samples
        inside one CasADi map-reduce (A and b never stored), normal equations of the
        column-scaled Gram matrix, and column-scaled QR for the candidates where those
        would lose accuracy. ``qr``: A and b for chunks of candidates into memory and
        batched QR for every candidate (the reference; 3-10x slower).
    jit : bool or None
        Compile the loops over samples to C (gcc or cc; 0.2-1 s the first time a model
        structure is swept, then taken from the compile cache). ``None`` (default): compile
        when N x candidates >= ``jit_min_work`` and a compiler is on the PATH.
    jit_min_work : float
        N x candidates from which ``jit=None`` compiles. Below it the per-sample function
        runs as NumPy operations over blocks of candidates x samples (no compile; CasADi's
        virtual machine where an operation has no NumPy form). Measured (one thread): NumPy
        40-70 ns per candidate x sample on NIST problems, 90 on the Pitot model; compiled
        SIMD code 18-35 and 16; compiling the Gram sums and A, b takes 0.5-1.4 s on an
        empty compile cache and a few ms from the cache, so from 1e6 compiling repays a
        cached library at once and loses at most about 1 s once per model structure. Below
        it, ``jit=None`` uses the Gram sums already compiled (by an earlier sweep of the same
        model structure, in this or an earlier session: the compile cache) at any size, and
        compiles nothing; ``jit=False`` never uses compiled sums.
    threads : int or None
        Threads over candidates (``method="gram"``; each runs its own compiled pass over
        the data); ``None``: one per core, with at least 16 candidates each. A static model's
        Gram pass splits its candidates only where each thread gets at least
        ``THREAD_MIN_WORK`` (1.5e5) candidate-samples x channels
        (:mod:`casest.two_stage.sweep.evaluators`): below that, handing the parts to threads
        costs more than it saves. Monte-Carlo workers pass 1.
    criterion : {"trace", "likelihood"}
        What ranks the candidates: ``trace`` (default), Tr[R] as in the paper; with one
        channel the two agree. ``likelihood``: the profile ML cost sum_j N_j/2 ln R_j, which
        does not depend on the channels' units; use it when the channels are in different
        units (m/s and rad, say), where Tr[R] is dominated by the channel with the largest
        numbers. Tr[R] is recorded either way.
    scheduler : str or None
        Address of a running ``dask.distributed`` scheduler (``"tcp://host:8786"``): the
        candidates are evaluated there as tasks of ``task_size`` candidates, each worker
        building the compiled evaluator once (:mod:`casest.two_stage.sweep.distributed`;
        extra ``parallel``). The results equal the local run's candidate by candidate; the
        refinement and the checks after the sweep run locally. ``None``: this process.
    task_size : int
        Candidates per task on a cluster (a task's overhead is milliseconds; its work should
        be much more: N x task_size >= 1e6 or so).
    condition_limit : float
        ``method="gram"``: a candidate whose column-scaled normal equations have a condition
        number above this (about 1e16 / condition_limit digits left) is re-solved by
        column-scaled QR of ``[A, z - b]`` itself, computed for those candidates only.
        Lower it for more accuracy on nearly collinear bases, raise it to keep more
        candidates on the fast path.
    error_bound : {"auto", True, False}
        Compute the paper's cost error E and bracket of Eq. 7-13 and its Eq. 17-18 as printed
        (:mod:`casest.two_stage.sweep.error_bound`; one more pass of A and b over every
        candidate, made the first time :attr:`Landscape.error_bound` is read: a report,
        ``to_dict``, a pickle). ``"auto"``: when candidates x N x n_outputs x (n1 + 1) <=
        ``error_bound_work``.
    error_bound_work : float
        The work above which ``error_bound="auto"`` skips it (1e7: about 0.1 s; the Pitot
        default sweep, at 6e7, would spend 0.6 s of its 2 s on it).
    radius : float or None
        The epsilon of the paper's feasible set ``||xi2 - xi2_nominal||_2 < epsilon`` (Sec. II.C,
        Step 2), in the swept parameters' own units, about their nominal values: candidates
        outside the ball keep their Tr[R] in the landscape but do not compete for the best
        (:attr:`Landscape.in_set`). None (default): the whole box.
    validity : {"best", "every"}
        Where the validity conditions apply: ``"best"`` (default) checks Eq. 17 and 18 at the
        best candidate, refines around it and gives the verdict; ``"every"`` is the paper's
        Step 2, the set S_xi2 of the candidates that satisfy both (``linearization_tol``,
        ``curvature_tol``) before the minimum of Tr[R] is taken among them (the model's
        Jacobian at every candidate: for a static model in one evaluation per block of
        candidates, :mod:`casest.two_stage.sweep.validity_batch`; a set left empty is refused).
        ``"best"`` is the default because on a grid Eq. 17 fails around a narrow global minimum,
        where the cost curves sharply between candidates: on random boxes about the NIST and
        Osborne 2 optima the filter on every candidate reached the optimum in 76 % of the runs,
        the default in 99 % (``docs/validation/optimum-net.md``).
    resolve_work : float
        A landscape a grid design does not resolve (Eq. 17 fails at a further local minimum:
        :attr:`Landscape.unresolved`, verdict ``"unresolved"``) is swept again with half the
        spacing along every swept axis (2^n2 times the candidates), as long as candidates x N x
        n_outputs stays at most this and the candidates at most 2^17 (ENSO's two periods over
        three decades: three such sweeps, 2000 to 128,000 candidates). 0: never. Explicit
        candidates and scattered designs (three or more swept parameters by default:
        :mod:`casest.two_stage.sweep.resolution` says why) are never swept again.
    """

    design: SweepDesign = "auto"
    n_candidates: int = 2000
    seed: int = 0
    linearization_tol: float = 0.05
    curvature_tol: float = 1e-8
    flat_spread: float = 0.25
    max_refinements: int = 10
    confidence: float = 0.99
    memory_mb: float = 256.0
    method: SweepMethod = "gram"
    jit: bool | None = None
    jit_min_work: float = 1e6
    threads: int | None = None
    criterion: SweepCriterion = "trace"
    scheduler: str | None = None
    task_size: int = 4096
    condition_limit: float = 1e10
    error_bound: ErrorBoundChoice = "auto"
    error_bound_work: float = 1e7
    radius: float | None = None
    validity: ValidityChecks = "best"
    resolve_work: float = 1e8

    def resolved_jit(self, n_samples: int, n_candidates: int) -> bool:
        """Whether the sweep's loops are compiled (see ``jit``).

        Parameters
        ----------
        n_samples, n_candidates : int

        Returns
        -------
        bool
        """
        if self.jit is None:
            from ..._casadi.numerics import compiler_available

            return n_samples * n_candidates >= self.jit_min_work and compiler_available()
        return bool(self.jit)

    def wants_error_bound(self, n_candidates: int, n_samples: int, n_outputs: int, n_linear: int) -> bool:
        """Whether the sweep computes the paper's error bound (see ``error_bound``).

        Parameters
        ----------
        n_candidates, n_samples, n_outputs, n_linear : int

        Returns
        -------
        bool
        """
        if self.error_bound == "auto":
            return n_candidates * n_samples * n_outputs * (n_linear + 1) <= self.error_bound_work
        return bool(self.error_bound)

    def resolved_threads(self, n_candidates: int) -> int:
        """Threads over candidates (see ``threads``).

        Parameters
        ----------
        n_candidates : int

        Returns
        -------
        int
        """
        from ..._casadi.numerics import available_cores

        if self.threads is None:
            return int(max(1, min(available_cores(), n_candidates // 16)))
        return max(1, int(self.threads))

    def __post_init__(self):
        check_option("SweepSettings.method", self.method, SweepMethod)
        check_option("SweepSettings.design", self.design, SweepDesign)
        if self.n_candidates < 1:
            raise OptionError("SweepSettings.n_candidates must be >= 1")
        if isinstance(self.task_size, bool) or not isinstance(self.task_size, (int, np.integer)) or self.task_size < 1:
            raise OptionError(f"SweepSettings.task_size must be a whole number of candidates >= 1, got "
                              f"{self.task_size!r}")
        if not (float(self.condition_limit) > 1.0):
            raise OptionError(f"SweepSettings.condition_limit must be a number above 1, got {self.condition_limit!r}")
        if self.error_bound not in ("auto", True, False):
            raise OptionError(f"SweepSettings.error_bound must be 'auto', True or False, got {self.error_bound!r}")
        check_option("SweepSettings.validity", self.validity, ValidityChecks)
        if self.radius is not None and not (isinstance(self.radius, (int, float, np.floating))
                                            and not isinstance(self.radius, bool) and float(self.radius) > 0
                                            and np.isfinite(self.radius)):
            raise OptionError(f"SweepSettings.radius must be a positive number (the epsilon of ||xi2 - xi2_nominal||"
                              f" < epsilon, in the parameters' units) or None for the whole box, got {self.radius!r}")
        if isinstance(self.resolve_work, bool) or not (isinstance(self.resolve_work, (int, float, np.integer,
                                                                                     np.floating))
                                                       and float(self.resolve_work) >= 0):
            raise OptionError(f"SweepSettings.resolve_work must be a number >= 0 (candidates x samples x outputs of "
                              f"the densest sweep again; 0 never sweeps again), got {self.resolve_work!r}")
        if self.criterion not in ("trace", "likelihood"):
            raise OptionError(f"SweepSettings.criterion must be 'trace' or 'likelihood', got {self.criterion!r}")
        if self.scheduler is not None and not (isinstance(self.scheduler, str) and self.scheduler.strip()):
            raise OptionError(f"SweepSettings.scheduler must be a dask scheduler's address such as "
                              f"'tcp://host:8786' (or None for this machine), got {self.scheduler!r}")
