"""The record a :class:`casest.DynamicModel` reads: its data set (time, inputs, outputs, the
states taken from the data), the columns derived from others, and the checks of a record's
time axis, columns and initial values."""

from __future__ import annotations

import weakref
from typing import Mapping

import numpy as np

from ..data.dataset import DataError, Dataset
from ..options import MissingOutputs


__all__ = ["DynamicRecords", "JITTER_TOLERANCE"]

#: Delays read the record in sample index (the kernel of :mod:`casest.models.delays`): time stamps
#: may stray from the uniform grid by at most this fraction of the sample time, which bounds the
#: error of a delayed sample's time by the same amount (AP2 record: 0.67 %).
JITTER_TOLERANCE = 0.05

#: records already accepted, each with the models that accepted it: a simulation reads its record
#: many times per estimate, and casest never changes a record once built
_ACCEPTED: "weakref.WeakKeyDictionary[Dataset, weakref.WeakSet]" = weakref.WeakKeyDictionary()


class DynamicRecords:
    """Mixed into :class:`casest.DynamicModel`, whose ``time``, ``input_delays``, ``output_delays``,
    ``segments`` and ``initial_from_data`` these methods read."""

    def complete_columns(self, columns: Mapping) -> Mapping:
        """``columns`` with the columns derived from others (the lagged samples of delayed inputs).

        Parameters
        ----------
        columns : mapping of str to array_like

        Returns
        -------
        mapping of str to array_like
        """
        return self.input_delays.complete_columns(columns)

    def derived_columns(self) -> set:
        """Names of the signal columns that data may leave out (:meth:`complete_columns` derives them).

        Returns
        -------
        set of str
        """
        return self.input_delays.derived_columns()

    def dataset(self, columns: Mapping, missing: MissingOutputs = "error", for_estimation: bool = True) -> Dataset:
        """A :class:`casest.Dataset` for this model: the time, the inputs and the outputs, plus
        a column per state whose initial value comes from the data (its first value is used).

        Parameters
        ----------
        columns : mapping of str to array_like, shape (N,) each
            ``t`` (s), the inputs, the outputs, and the states taken from the data.
        missing : {"error", "allow"}
            Whether NaN outputs are refused or mark samples not measured.
        for_estimation : bool
            False for a record only filtered or smoothed (any length; see :class:`Dataset`).

        Returns
        -------
        Dataset
        """
        return Dataset(self, columns, extra=self.initial_from_data, missing=missing, for_estimation=for_estimation)

    def check_data(self, data: Dataset) -> None:
        """Raise a :class:`DataError` if the data do not fit this model (columns, time, initial states).

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        None

        Raises
        ------
        DataError
            Missing columns, a time axis that does not increase, missing initial states.
        """
        if self in _ACCEPTED.get(data, ()):
            return
        data.check_model(self)
        t = data.signals[:, 0]
        steps = np.diff(t)
        if np.any(steps <= 0):
            k = int(np.flatnonzero(steps <= 0)[0])
            raise DataError(f"the time column {self.time!r} must increase strictly; it does not at rows {k} and {k + 1} "
                            f"({t[k]:.6g} s, {t[k + 1]:.6g} s): sort the samples or drop the repeated ones")
        dt = self.input_delays.sample_time or self.output_delays.sample_time
        if dt:
            self._check_uniform_enough(data, t, dt)
        absent = [n for n in self.initial_from_data if n not in data.extra]
        if absent:
            raise DataError(f"the initial values of states {absent} come from the data, but the data have no column "
                            f"named so; build the data with DynamicModel.dataset(columns) including them")
        _ACCEPTED.setdefault(data, weakref.WeakSet()).add(self)

    def _check_uniform_enough(self, data: Dataset, t: np.ndarray, dt: float) -> None:
        """Delays interpolate in sample index: refuse time stamps that stray from the uniform grid
        k * dt by more than :data:`JITTER_TOLERANCE` of dt (within each segment)."""
        starts = np.zeros(t.size, dtype=bool)
        starts[0] = True
        if self.segments is not None:  # stacked experiments: each restarts the grid
            starts |= data.column(self.segments.start) > 0.5
        first = np.maximum.accumulate(np.where(starts, np.arange(t.size), 0))
        deviation = np.abs(t - t[first] - (np.arange(t.size) - first) * dt)
        k = int(np.argmax(deviation))
        if deviation[k] > JITTER_TOLERANCE * dt:
            raise DataError(f"delays interpolate between samples {dt:g} s apart (sample_time), but the record's time "
                            f"at row {k} ({t[k]:.6g} s) is {deviation[k]:.3g} s off the uniform grid, more than "
                            f"{JITTER_TOLERANCE:.0%} of a sample: give the DynamicModel the record's mean interval "
                            f"as sample_time ({np.mean(np.diff(t)):.6g} s here), or resample the record uniformly")

    def initial_values(self, data: Dataset) -> np.ndarray:
        """The data's values of the states whose initial value comes from the data, shape (n,).

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        ndarray, shape (len(initial_from_data),)
        """
        return np.array([float(data.extra[n][0]) for n in self.initial_from_data])

    # ------------------------------------------------------------------ discretisation and simulation
