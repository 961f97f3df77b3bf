"""Per-sample data sets keyed by the model's signal and output names."""

from __future__ import annotations

import csv
import io
import os
from typing import Mapping, Protocol, Sequence

import numpy as np

from ..errors import DataError
from ..status import Note, NoteCode
from .columns import check_column_names, check_values, column_array
from .csv_text import csv_columns, csv_header, read_text, sniff_delimiter
from .files import atomic_write_text
from .units import convert_to_model_units
from ..options import MissingOutputs



__all__ = ["Dataset", "DataError", "atomic_write_text", "DeclaredModel"]


class DeclaredModel(Protocol):
    """What a data set reads of a model (a :class:`casest.Model` or :class:`casest.DynamicModel`):
    its name and the names of its signals and outputs, and their units."""

    name: str
    signal_names: tuple
    output_names: tuple
    n_signals: int
    n_outputs: int


class Dataset:
    """Measured samples for one model: known signals X and measured outputs Z.

    Parameters
    ----------
    model : Model or DynamicModel
        Fixes the column order.
    columns : mapping of str to array_like, each of shape (N,)
        One entry per signal and per output channel of the model. Extra names raise
        :class:`DataError` unless listed in ``extra``.
    extra : sequence of str, optional
        Names of further columns to keep (e.g. ``time``) in :attr:`extra`.
    missing : {"error", "allow"}
        What a NaN in an output column means: an error that names the rows (default), or
        "not measured at this sample" (``"allow"``): that residual leaves every sum and
        each channel's noise variance uses its own count N_j. Missing signals are always
        an error.
    for_estimation : bool
        Check that the record holds more measurements than the parameters and noise
        variances to estimate (default). A record only filtered or smoothed (a Kalman filter
        runs on any length) may set it False; an estimate checks it again.

    Attributes
    ----------
    signals : ndarray, shape (N, n_signals)
        Known states and inputs, model order.
    outputs : ndarray, shape (N, n_outputs)
        Measurements z_k, model order.
    extra : dict of str to ndarray (N,)
        Columns the model does not use.
    observed : ndarray of bool, shape (N, n_outputs), or None
        Which outputs were measured (``None``: all of them).
    undeclared_units : dict of str to str
        Columns whose file header gives a unit the model does not declare (name: unit),
        used as they are; an estimate from these data is not trusted until the model
        declares the unit (:meth:`from_csv`).
    alignment : dict of str to AlignedColumn
        Columns resampled onto the data set's time base (:meth:`from_ulog`): source field,
        interpolated or held, source rate and largest gap; empty for data read as sampled.
    time_ordered : bool
        The samples are a record in time order (a log), so that an estimate of a static model
        analyses its residuals in time too (autocorrelation, colored-residual std). Set by
        :meth:`from_ulog` and by :meth:`from_mat` with ``time_ordered=True``; a dynamic
        model's data are always in time order.

    Raises
    ------
    DataError
        A missing or unknown column, columns of different lengths, a non-1-D column,
        NaN or infinite values (the message gives the rows), or fewer samples than the
        estimation needs.
    """

    def __init__(
        self,
        model: DeclaredModel,
        columns: Mapping[str, Sequence[float] | np.ndarray],
        extra: Sequence[str] = (),
        missing: MissingOutputs = "error",
        for_estimation: bool = True,
    ):
        if missing not in ("error", "allow"):
            raise DataError(f"missing must be 'error' or 'allow', got {missing!r}")
        self.model_name = model.name
        self.signal_names = model.signal_names
        self.output_names = model.output_names
        complete = getattr(model, "complete_columns", None)  # columns the model derives (lagged inputs)
        if complete is not None:
            columns = complete(columns)
        needed = list(model.signal_names) + list(model.output_names)
        check_column_names(model, columns, needed, extra)
        arrays = {}
        for name in needed + [e for e in extra if e in columns]:
            arrays[name] = column_array(name, columns[name], arrays, needed)
            if name in needed:
                check_values(name, arrays[name], model, allow_missing=missing == "allow")
        n = arrays[needed[0]].size if needed else 0
        if n == 0:
            raise DataError("the dataset has no samples")
        self.signals = (
            np.column_stack([arrays[s] for s in model.signal_names])
            if model.n_signals
            else np.zeros((n, 0))
        )
        self.outputs = np.column_stack([arrays[o] for o in model.output_names])
        self.extra = {e: arrays[e] for e in extra if e in arrays}
        self.undeclared_units: dict[str, str] = {}
        self.alignment: dict = {}
        self.time_ordered = False
        seen = np.isfinite(self.outputs)
        self.observed = None if seen.all() else seen
        empty = [o for o, c in zip(self.output_names, seen.sum(axis=0)) if c == 0]
        if empty:
            raise DataError(f"output(s) {empty} were not measured at any sample; drop them from the model")
        if for_estimation:
            self.check_size(model)

    # -- constructors -------------------------------------------------------------------
    @classmethod
    def from_arrays(
        cls,
        model: DeclaredModel,
        signals: np.ndarray,
        outputs: np.ndarray,
        missing: MissingOutputs = "error",
    ) -> "Dataset":
        """Build from model-ordered matrices.

        Parameters
        ----------
        signals : ndarray, shape (N, n_signals)
        outputs : ndarray, shape (N, n_outputs) or (N,) for one output

        Parameters
        ----------
        model : Model or DynamicModel
        signals : ndarray, shape (N, n_signals)
            In the model's signal order (a dynamic model's: time, then the inputs).
        outputs : ndarray, shape (N, n_outputs) or (N,) for one output
        missing : {"error", "allow"}
            Whether NaN outputs are refused or mark samples not measured.

        Returns
        -------
        Dataset
        """
        signals = np.asarray(signals, dtype=float)
        outputs = np.asarray(outputs, dtype=float)
        if signals.ndim == 1 and model.n_signals == 1:
            signals = signals[:, None]
        if outputs.ndim == 1 and model.n_outputs == 1:
            outputs = outputs[:, None]
        if signals.ndim != 2 or signals.shape[1] != model.n_signals:
            raise DataError(
                f"signals must have shape (N, {model.n_signals}) for {list(model.signal_names)}, "
                f"got {signals.shape}"
            )
        if outputs.ndim != 2 or outputs.shape[1] != model.n_outputs:
            raise DataError(
                f"outputs must have shape (N, {model.n_outputs}) for {list(model.output_names)}, "
                f"got {outputs.shape}"
            )
        if signals.shape[0] != outputs.shape[0] and model.n_signals:
            raise DataError(
                f"signals have {signals.shape[0]} rows but outputs have {outputs.shape[0]}"
            )
        columns = {n: signals[:, i] for i, n in enumerate(model.signal_names)}
        columns.update({n: outputs[:, i] for i, n in enumerate(model.output_names)})
        return cls(model, columns, missing=missing)

    @classmethod
    def from_csv(cls, model: DeclaredModel, path: str | os.PathLike, delimiter: str | None = None,
                 missing: MissingOutputs = "error") -> "Dataset":
        """Read a CSV file with a header row.

        Header cells are column names, optionally followed by a unit in brackets
        (``V_N [m/s]``). A signal whose header unit differs from the unit the model
        declares is converted (with pint, ``pip install 'casest[units]'``) or refused;
        it is never read as if it were in the declared unit. Columns the model does not
        use are kept in :attr:`extra`. A UTF-8 byte-order mark is ignored.

        Parameters
        ----------
        model : Model or DynamicModel
        path : str or path-like
        delimiter : str, optional
            Field separator; default: comma, semicolon or tab, whichever the header uses.
        missing : {"error", "allow"}
            See :class:`Dataset`; an empty field is NaN.

        Raises
        ------
        DataError
            A missing, empty, binary or non-UTF-8 file, a folder, a header cell that does
            not parse, duplicated column names, a unit that cannot be converted, a field
            that is not a number, rows of the wrong length (each with the line number).

        Returns
        -------
        Dataset
        """
        path = os.fspath(path)
        lines = read_text(path).splitlines()
        body = [(k + 1, line) for k, line in enumerate(lines) if line.strip()]
        if not body:
            raise DataError(f"data file {path!r} is empty")
        delimiter = delimiter or sniff_delimiter(body[0][1], path)
        rows = list(csv.reader([line for _, line in body], delimiter=delimiter))
        header, rows, line_numbers = rows[0], rows[1:], [k for k, _ in body[1:]]
        names, units = csv_header(model, header, path)
        arrays = csv_columns(names, rows, line_numbers, path, delimiter)
        undeclared = convert_to_model_units(model, arrays, units, path)
        needed = set(model.signal_names) | set(model.output_names)
        dataset = cls(model, arrays, extra=[n for n in names if n not in needed], missing=missing)
        dataset.undeclared_units = undeclared
        return dataset

    @classmethod
    def from_dataframe(cls, model: DeclaredModel, frame, units: Mapping[str, str] | None = None,
                       missing: MissingOutputs = "error") -> "Dataset":
        """A record from a pandas data frame (needs ``casest[frames]``).

        Columns are matched to the model's signals and outputs by name; a label may carry its
        unit in brackets as a CSV header does (``"V_N [m/s]"``), or ``units`` gives it. A
        column in another unit than the model declares is converted (pint) or refused. A
        dynamic model's time may be the index (datetime or timedelta: seconds from the first
        row; numeric: seconds). Other columns are kept in :attr:`extra`.

        Parameters
        ----------
        model : Model or DynamicModel
        frame : pandas.DataFrame
        units : mapping of str to str, optional
            Column name -> unit.
        missing : {"error", "allow"}
            See :class:`Dataset`; NaN or missing values are missing samples.

        Returns
        -------
        Dataset

        Raises
        ------
        DataError
            As :meth:`from_csv`, for the frame's columns; a time index that is not increasing.
        """
        from .frames import frame_columns

        columns, undeclared = frame_columns(model, frame, units)
        needed = set(model.signal_names) | set(model.output_names)
        dataset = cls(model, columns, extra=[n for n in columns if n not in needed], missing=missing)
        dataset.undeclared_units = undeclared
        return dataset

    @classmethod
    def from_mat(cls, model: DeclaredModel, path: str | os.PathLike, variables: Mapping | None = None,
                 units: Mapping[str, str] | None = None, missing: MissingOutputs = "error", extra: Sequence[str] = (),
                 sample_time: float | None = None, time_ordered: bool = False) -> "Dataset":
        """Read a MATLAB ``.mat`` record (v4 to v7, SciPy), nested structs included.

        Parameters
        ----------
        model : Model or DynamicModel
            Fixes the columns read: signals, outputs and the states started from the data.
        path : str or os.PathLike
        variables : mapping, optional
            Column name -> where it is in the file: a variable name, a struct path with an
            optional channel index (``"flight.response.w[1]"``: the second row of a 3 x N
            field), or ``(variable, k)`` for column k of an N x m matrix
            (:mod:`casest.data.matfile`). Unlisted columns are the variable of their name.
        units : mapping of str to str, optional
            Column name -> the unit the file holds it in (converted to the model's).
        missing : {"error", "allow"}
        extra : sequence of str
            Further columns to read and keep in :attr:`extra` (mapped by ``variables`` too).
        sample_time : float, optional
            Build a dynamic model's time column as k * sample_time (s) when the file has none.
        time_ordered : bool
            The samples are a record in time (see :attr:`time_ordered`).

        Returns
        -------
        Dataset
        """
        from .matfile import read_mat_columns

        columns = read_mat_columns(model, path, variables=variables, units=units, extra=extra,
                                   sample_time=sample_time)
        needed = set(model.signal_names) | set(model.output_names)
        dataset = cls(model, columns.arrays, extra=[n for n in columns.arrays if n not in needed], missing=missing)
        dataset.undeclared_units = columns.undeclared_units
        dataset.time_ordered = bool(time_ordered)
        return dataset

    @classmethod
    def from_ulog(cls, model: DeclaredModel, path: str | os.PathLike, fields: Mapping[str, str], *,
                  sample_time: float | None = None, time_base: str | None = None, hold: Sequence[str] = (),
                  extra: Sequence[str] = (), units: Mapping[str, str] | None = None,
                  missing: MissingOutputs = "error") -> "Dataset":
        """Read chosen fields of a PX4 ULog log (``pyulog``, ``pip install 'casest[logs]'``),
        aligned onto one time base (:mod:`casest.data.ulog`).

        Parameters
        ----------
        model : Model or DynamicModel
        path : str or os.PathLike
        fields : mapping of str to str
            Column name -> ``"topic.field"`` or ``"topic[multi_id].field"``.
        sample_time : float, optional
            A uniform time base of this step (s); default: the time stamps of the chosen
            topic with the most samples.
        time_base : str, optional
            A topic whose time stamps are the time base.
        hold : sequence of str
            Discrete columns (modes, flags): their last logged value is held, not interpolated.
        extra : sequence of str
            Further columns to keep in :attr:`extra` (a static model's time base is kept as
            ``"time"``, s).
        units : mapping of str to str, optional
            Column name -> the unit it is logged in (converted to the model's).
        missing : {"error", "allow"}

        Returns
        -------
        Dataset
            With :attr:`alignment` saying how each column was aligned.
        """
        from .ulog import read_ulog_columns

        columns = read_ulog_columns(model, path, fields, sample_time=sample_time, time_base=time_base, hold=hold,
                                    extra=extra, units=units)
        needed = set(model.signal_names) | set(model.output_names)
        dataset = cls(model, columns.arrays, extra=[n for n in columns.arrays if n not in needed], missing=missing)
        dataset.undeclared_units = columns.undeclared_units
        dataset.alignment = columns.alignment
        dataset.time_ordered = True
        return dataset

    # -- output -------------------------------------------------------------------------
    def to_csv(self, path: str | os.PathLike, units: Mapping[str, str] | None = None) -> None:
        # units: column -> unit written in the header (e.g. the model's signal and output units)
        """Write all columns (signals, outputs, extra) to CSV atomically, full precision.

        Parameters
        ----------
        path : str or os.PathLike
        units : mapping of str to str, optional
            Units written in the header brackets (default: the model's declared units).

        Returns
        -------
        None
        """
        names = list(self.signal_names) + list(self.output_names) + list(self.extra)
        data = np.column_stack([self.signals, self.outputs] + [self.extra[e] for e in self.extra])
        units = dict(units or {})
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow([f"{n} [{units[n]}]" if units.get(n) else n for n in names])
        for row in data:
            writer.writerow([repr(float(v)) for v in row])
        atomic_write_text(path, buf.getvalue())

    # -- views --------------------------------------------------------------------------
    @property
    def n_samples(self) -> int:
        return self.outputs.shape[0]

    def __len__(self) -> int:
        return self.n_samples

    def column(self, name: str) -> np.ndarray:
        """One column by name (signal, output or extra), shape (N,).

        Parameters
        ----------
        name : str

        Returns
        -------
        ndarray, shape (N,)

        Raises
        ------
        DataError
            No column of that name (the message lists the columns).
        """
        if name in self.signal_names:
            return self.signals[:, self.signal_names.index(name)]
        if name in self.output_names:
            return self.outputs[:, self.output_names.index(name)]
        if name in self.extra:
            return self.extra[name]
        raise DataError(f"no column {name!r} in this dataset")

    def subset(self, rows) -> "Dataset":
        """A new Dataset with the selected rows (slice, index array or boolean mask).

        Parameters
        ----------
        rows : slice, ndarray of int or ndarray of bool

        Returns
        -------
        Dataset
        """
        new = object.__new__(Dataset)
        new.model_name = self.model_name
        new.signal_names = self.signal_names
        new.output_names = self.output_names
        new.signals = np.ascontiguousarray(self.signals[rows])
        new.outputs = np.ascontiguousarray(self.outputs[rows])
        new.extra = {k: v[rows] for k, v in self.extra.items()}
        new.undeclared_units = dict(self.undeclared_units)
        new.alignment = dict(getattr(self, "alignment", {}))
        new.time_ordered = getattr(self, "time_ordered", False)
        new.observed = None if self.observed is None else np.ascontiguousarray(self.observed[rows])
        if new.observed is not None and new.observed.all():
            new.observed = None
        if new.n_samples == 0:
            raise DataError("the selected subset has no samples")
        return new

    def check_size(self, model: DeclaredModel) -> None:
        """Raise if there are too few measurements for the parameters and the noise R.

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        None

        Raises
        ------
        DataError
            Fewer measurements than parameters plus noise variances.
        """
        needed = model.n_parameters + model.n_outputs + 1
        have = int(self.observed_counts().sum())
        if have < needed:
            raise DataError(
                f"{self.n_samples} samples x {model.n_outputs} outputs = {have} measurements, "
                f"but {model.n_parameters} parameters and {model.n_outputs} noise variances "
                f"need at least {needed}; collect more samples (to filter or smooth a short record, which needs "
                "no estimate, build it with for_estimation=False)"
            )

    def check_model(self, model: DeclaredModel) -> None:
        """Raise if this dataset was built for a model with other columns.

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        None

        Raises
        ------
        DataError
            The columns differ (the message names them).
        """
        if (
            tuple(self.signal_names) != model.signal_names
            or tuple(self.output_names) != model.output_names
        ):
            raise DataError(
                f"dataset columns (signals {list(self.signal_names)}, outputs "
                f"{list(self.output_names)}) do not match model {model.name!r} (signals "
                f"{list(model.signal_names)}, outputs {list(model.output_names)})"
            )

    def output_mean_square(self) -> np.ndarray:
        """Mean of z_j**2 per channel over the measured samples, shape (n_outputs,), for the noise floor.

        Returns
        -------
        ndarray, shape (n_outputs,)
            Unit of each output squared.
        """
        return np.nanmean(self.outputs**2, axis=0) if self.observed is not None else np.mean(self.outputs**2, axis=0)

    @property
    def has_missing(self) -> bool:
        """True when some outputs were not measured at some samples."""
        return self.observed is not None

    def observed_counts(self) -> np.ndarray:
        """N_j: the number of measured samples per output, shape (n_outputs,).

        Returns
        -------
        ndarray of int, shape (n_outputs,)
        """
        if self.observed is None:
            return np.full(len(self.output_names), self.n_samples)
        return self.observed.sum(axis=0)

    def output_mask(self) -> np.ndarray:
        """1.0 where an output was measured, 0.0 where not, shape (N, n_outputs).

        Returns
        -------
        ndarray, shape (N, n_outputs)
        """
        if self.observed is None:
            return np.ones_like(self.outputs)
        return self.observed.astype(float)

    def filled_outputs(self) -> np.ndarray:
        """The outputs with 0.0 where not measured (for sums that multiply by the mask), shape (N, n_outputs).

        Returns
        -------
        ndarray, shape (N, n_outputs)
        """
        return self.outputs if self.observed is None else np.where(self.observed, self.outputs, 0.0)

    def __repr__(self) -> str:
        return (
            f"Dataset(N={self.n_samples}, signals={list(self.signal_names)}, "
            f"outputs={list(self.output_names)})"
        )


def undeclared_units_note(undeclared: Mapping[str, str]) -> Note | None:
    """The estimate's note for data columns whose file unit the model does not declare
    (``{name: unit}``, see :attr:`Dataset.undeclared_units`), or None when there are none."""
    if not undeclared:
        return None
    units = ", ".join(f"{name} [{unit}]" for name, unit in undeclared.items())
    return Note(f"the data file gives units the model does not declare ({units}); the values were used as they "
                "are: declare each with Signal(name, unit=...) (or the output's unit) and casest converts the data",
                NoteCode.UNITS)


def alignment_note(alignment: Mapping) -> Note | None:
    """The estimate's note for columns a log reader aligned onto one time base (``{name:
    AlignedColumn}``, see :attr:`Dataset.alignment`), or None when there are none."""
    if not alignment:
        return None
    lines = "; ".join(f"{name}: {column.describe()}" for name, column in alignment.items())
    return Note(f"the data were aligned onto one time base ({lines}); interpolation smooths noise between samples "
                "and a held column lags by up to one of its intervals", NoteCode.ALIGNMENT)
