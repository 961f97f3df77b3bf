"""The CasADi side of a :class:`casest.Problem`: its data as the NLPs' parameter, the compiled
per-sample sums of the ML cost and their exact Hessian, and the cost as an expression (the
numeric residuals, costs and noise live in :mod:`casest.problem.problem`)."""

from __future__ import annotations

from contextlib import contextmanager

import casadi as ca
import numpy as np

from ..backend.sums import Record


__all__ = ["ProblemGraphs"]


class ProblemGraphs:
    """The data vector, the data argument, the sums and the cost graphs of a problem (mixed into
    :class:`casest.Problem`, whose ``data``, ``measurement``, ``n_samples``, ``masked``,
    ``noise_term``, ``n_noise`` and ``penalty`` they read)."""

    def data_vector(self) -> np.ndarray:
        """The NLP parameter ``p = [vec(X); vec(Z)]`` (column-major, sample by sample).

        With missing outputs Z is ``[z; m]`` per sample: z with 0 where not measured, m the mask.
        A dynamic model's is ``[t; vec(U); vec(Z); x0_data]`` (times, inputs, outputs and the
        initial values taken from the data).

        Returns
        -------
        ndarray, shape (n_p,)
        """
        return self.measurement.data_vector(self.data, self.masked)

    @contextmanager
    def data_argument(self):
        """The data argument of :meth:`cost_hessian` (and of stage 2's NLP), valid inside the
        ``with`` block: a bound :meth:`record`'s handle for long records
        (:func:`casest.backend.sums.data_outside_graph`), else :meth:`data_vector`.

        Returns
        -------
        context manager
            Yields the data argument (a record handle or the data vector).
        """
        if not self.measurement.data_outside_graph(self.n_samples):
            yield self.data_vector()
            return
        with self.record() as record:
            yield np.array([record.handle])

    def record(self) -> Record:
        """The data of a static problem as a :class:`casest.backend.sums.Record` of (X, Z), the data
        argument of the bound sums (stage 2, :meth:`cost_hessian`); bind it with ``with``.

        Returns
        -------
        Record
        """
        return self.measurement.record(self.data, self.masked)

    # ------------------------------------------------------------------ symbolic parts
    def sums(self, scale=None, threads: int | None = None, jit: bool = False, jit_flags=("-O2",)):
        """The compiled per-sample sums of J/N, its gradient and Hessian (:class:`casest.backend.sums.MLSums`)
        in ``w = [theta / scale; noise vector]``. Static models only: a dynamic model's states
        depend on theta, so its derivatives go through the simulation (:meth:`cost_expression`).

        Parameters
        ----------
        scale : array_like, shape (n_parameters,), optional
        threads : int, optional
        jit : bool
        jit_flags : tuple of str

        Returns
        -------
        MLSums
        """
        return self.measurement.ml_sums(self.n_samples, scale, threads, jit, jit_flags, self.masked, self.noise_term)

    def cost_hessian(self, threads: int | None = None, jit: bool = False, jit_flags=("-O2",)) -> ca.Function:
        """``(theta, noise vector, data) -> (J, H)``: Eq. 6 (without the prior penalty) and its exact
        Hessian in (physical theta, noise vector), from the per-sample sums (a dynamic model:
        CasADi's exact Hessian through the simulation).

        ``data``: a static problem's :meth:`data_argument` (a :meth:`record` handle for long
        records, else the data vector), a dynamic one's :meth:`data_vector`.

        Parameters
        ----------
        threads : int, optional
        jit : bool
        jit_flags : tuple of str

        Returns
        -------
        casadi.Function
        """
        return self.measurement.cost_hessian(self.n_samples, self.masked, self.noise_term, threads, jit,
                                             jit_flags)

    def cost_expression(self, theta: ca.MX, noise: ca.MX, p: ca.MX) -> ca.MX:
        """J (with the prior penalty) as a CasADi expression (see :func:`ml_cost_expression`;
        a dynamic model: :func:`dynamic_cost_expression`).

        Parameters
        ----------
        theta : casadi.MX, shape (n_parameters, 1)
            Physical units.
        noise : casadi.MX
            The noise block (``ln R`` or the log-Cholesky vector).
        p : casadi.MX
            The data vector (:meth:`data_vector`).

        Returns
        -------
        casadi.MX
        """
        return self.measurement.cost_expression(self.n_samples, theta, noise, p, self.masked, self.noise_term,
                                                self.penalty)
