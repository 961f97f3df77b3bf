"""Sums over samples for many candidates at once, without a compiler: the instruction list of a
per-sample SX function run as NumPy operations on arrays of candidates x samples.

CasADi's virtual machine evaluates one candidate and one sample at a time (about 200 ns per
sample of a small NIST model, call overhead included). Here each instruction of the function is one
NumPy operation on a whole block of candidates and samples: data-only values have shape (1, N),
candidate-only values (M, 1), so what depends on one side only is computed once per block,
and nothing is compiled. This is the stage-1 path below the sweep's compile threshold
(``SweepSettings.jit_min_work``); the compiled SIMD C of :mod:`.lane_sums` takes over above it.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

__all__ = ["ArrayProgram", "ArraySum", "ArrayValues"]

#: Candidates x samples per block: the work arrays stay in the processor's cache.
BLOCK_ELEMENTS = 65536


def _as_float(mask):
    return np.multiply(mask, 1.0)


def _if_else_zero(condition, value):
    return np.where(np.not_equal(condition, 0.0), value, 0.0)


def _erf(a):
    from scipy.special import erf

    return erf(a)


_UNARY = {ca.OP_ASSIGN: lambda a: a, ca.OP_NEG: np.negative, ca.OP_TWICE: lambda a: np.add(a, a),
          ca.OP_SQ: np.square, ca.OP_INV: lambda a: np.divide(1.0, a), ca.OP_NOT: lambda a: _as_float(np.equal(a, 0.0)),
          ca.OP_FABS: np.abs, ca.OP_SQRT: np.sqrt, ca.OP_SIGN: np.sign, ca.OP_FLOOR: np.floor, ca.OP_CEIL: np.ceil,
          ca.OP_SIN: np.sin, ca.OP_COS: np.cos, ca.OP_TAN: np.tan, ca.OP_EXP: np.exp, ca.OP_LOG: np.log,
          ca.OP_ASIN: np.arcsin, ca.OP_ACOS: np.arccos, ca.OP_ATAN: np.arctan, ca.OP_SINH: np.sinh,
          ca.OP_COSH: np.cosh, ca.OP_TANH: np.tanh, ca.OP_ASINH: np.arcsinh, ca.OP_ACOSH: np.arccosh,
          ca.OP_ATANH: np.arctanh, ca.OP_ERF: _erf, ca.OP_LOG1P: np.log1p, ca.OP_EXPM1: np.expm1}
_BINARY = {ca.OP_ADD: np.add, ca.OP_SUB: np.subtract, ca.OP_MUL: np.multiply, ca.OP_DIV: np.divide,
           ca.OP_LT: lambda a, b: _as_float(np.less(a, b)), ca.OP_LE: lambda a, b: _as_float(np.less_equal(a, b)),
           ca.OP_EQ: lambda a, b: _as_float(np.equal(a, b)), ca.OP_NE: lambda a, b: _as_float(np.not_equal(a, b)),
           ca.OP_AND: lambda a, b: _as_float(np.logical_and(np.not_equal(a, 0.0), np.not_equal(b, 0.0))),
           ca.OP_OR: lambda a, b: _as_float(np.logical_or(np.not_equal(a, 0.0), np.not_equal(b, 0.0))),
           ca.OP_IF_ELSE_ZERO: _if_else_zero, ca.OP_POW: np.power, ca.OP_CONSTPOW: np.power,
           ca.OP_ATAN2: np.arctan2, ca.OP_HYPOT: np.hypot, ca.OP_FMIN: np.fmin, ca.OP_FMAX: np.fmax,
           ca.OP_FMOD: np.fmod, ca.OP_COPYSIGN: np.copysign}

# step kinds of the program
_DATA, _CANDIDATE, _CONST, _APPLY1, _APPLY2, _OUTPUT = range(6)


def _program(fun: ca.Function, n_data: int) -> list[tuple] | None:
    """The instructions as steps ``(kind, target, ...)``; None for an operation with no NumPy form."""
    sizes = [fun.nnz_in(k) for k in range(fun.n_in())]
    offsets = [sum(sizes[:k]) - (0 if k < n_data else sum(sizes[:n_data])) for k in range(len(sizes))]
    steps = [_step(fun, k, n_data, offsets) for k in range(fun.n_instructions())]
    return None if None in steps else steps


def _step(fun: ca.Function, k: int, n_data: int, offsets: list) -> tuple | None:
    """Instruction k as a step, or None for an operation with no NumPy form."""
    op, ins, outs = fun.instruction_id(k), fun.instruction_input(k), fun.instruction_output(k)
    if op == ca.OP_INPUT:
        arg, nz = ins
        return (_DATA if arg < n_data else _CANDIDATE, outs[0], offsets[arg] + nz)
    if op == ca.OP_OUTPUT:
        return (_OUTPUT, outs[1], ins[0])
    if op == ca.OP_CONST:
        return (_CONST, outs[0], np.float64(fun.instruction_constant(k)))
    if op in _UNARY:
        return (_APPLY1, outs[0], _UNARY[op], ins[0])
    if op in _BINARY:
        return (_APPLY2, outs[0], _BINARY[op], ins[0], ins[1])
    return None


@dataclass(frozen=True)
class ArrayProgram:
    """A per-sample SX function's instructions as array steps, independent of the data.

    Attributes
    ----------
    steps : tuple of tuple
        ``(kind, target, ...)`` per instruction.
    n_work : int
        Work slots the steps use.
    n_out : int
        Entries of the output.
    n_values : int
        Candidate values per candidate (the inputs after the data).
    """

    steps: tuple
    n_work: int
    n_out: int
    n_values: int

    @classmethod
    def of(cls, per_sample: ca.Function, n_data: int) -> "ArrayProgram | None":
        """The program of ``per_sample`` whose first ``n_data`` inputs are data, or None (see
        :meth:`ArraySum.build`)."""
        steps = _program(per_sample, n_data) if _dense_sx(per_sample) else None
        if steps is None:
            return None
        n_work = 1 + max([s[1] for s in steps if s[0] != _OUTPUT] or [0])
        n_values = sum(per_sample.nnz_in(k) for k in range(n_data, per_sample.n_in()))
        return cls(tuple(steps), n_work, per_sample.nnz_out(0), n_values)


def _dense_sx(fun: ca.Function) -> bool:
    """An SX function with dense inputs and one dense output (what a program can take)."""
    return (fun.is_a("SXFunction") and fun.n_out() == 1 and fun.sparsity_out(0).is_dense()
            and all(fun.nnz_in(k) == fun.numel_in(k) for k in range(fun.n_in())))


class ArraySum:
    """``sum_k f(data_k, candidate)`` for many candidates, evaluated as NumPy array operations.

    Built by :meth:`build`; called like :class:`~casest.backend.lane_sums.LaneSum`, whose
    compiled path it stands in for when compiling would not repay itself. NumPy releases the
    GIL inside its operations, so threads over candidates overlap in part.
    """

    summed = True

    def __init__(self, steps: list[tuple], n_work: int, n_out: int, n_values: int, data: np.ndarray):
        self._steps, self._n_work = steps, n_work
        self.n_out, self.n_values = n_out, n_values
        self.n_samples = data.shape[0]
        self._columns = [np.ascontiguousarray(data[:, j])[None, :] for j in range(data.shape[1])]
        self.block = max(1, BLOCK_ELEMENTS // max(self.n_samples, 1))

    @classmethod
    def build(cls, per_sample: ca.Function, data: list[np.ndarray], program: "ArrayProgram | None" = None
              ) -> "ArraySum | None":
        """The array evaluation of ``per_sample`` over the rows of ``data``, or None.

        Parameters
        ----------
        per_sample : casadi.Function
            SX function of one sample: its first ``len(data)`` inputs take one row of each
            data array, the others a candidate's values; one dense output column.
        data : list of ndarray
            Per-sample arrays, each (N, size of the matching input).
        program : ArrayProgram, optional
            ``ArrayProgram.of(per_sample, len(data))`` made earlier (it does not depend on the data).

        Returns
        -------
        ArraySum or None
            None when ``per_sample`` is not an SX function with dense inputs and one dense
            output, or uses an operation with no NumPy form here (a call to another function,
            say): the caller keeps CasADi's virtual machine then.
        """
        program = program or ArrayProgram.of(per_sample, len(data))
        if program is None:
            return None
        columns = [np.asarray(d, dtype=float).reshape(d.shape[0], -1) for d in data]
        return cls(list(program.steps), program.n_work, program.n_out, program.n_values, np.hstack(columns))

    def blocks(self, n_candidates: int) -> int:
        """Blocks of candidates that ``n_candidates`` make (each is one pass of the program)."""
        return max(1, -(-n_candidates // self.block))

    def __call__(self, values: np.ndarray) -> np.ndarray:
        """Sums for M candidates.

        Parameters
        ----------
        values : ndarray, shape (M, n_values)
            Each candidate's values (the non-data inputs of ``per_sample``, concatenated).

        Returns
        -------
        ndarray, shape (M, n_out)
        """
        return self._fill(values, np.empty((values.shape[0], self.n_out)))

    def _fill(self, values: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``out`` (first axis: the M candidates) filled block by block; returned."""
        for start in range(0, values.shape[0], self.block):
            stop = min(values.shape[0], start + self.block)
            self._block(values[start:stop], out[start:stop])
        return out

    def _block(self, values: np.ndarray, out: np.ndarray) -> None:
        """One block of candidates: every instruction once, over (candidates, samples) arrays."""
        M, N = values.shape[0], self.n_samples
        candidate = [values[:, j : j + 1] for j in range(values.shape[1])]
        w = [None] * self._n_work
        with np.errstate(all="ignore"):  # NaN and inf reach the sums, as in the compiled code
            for step in self._steps:
                kind = step[0]
                if kind == _APPLY2:
                    w[step[1]] = step[2](w[step[3]], w[step[4]])
                elif kind == _APPLY1:
                    w[step[1]] = step[2](w[step[3]])
                elif kind == _DATA:
                    w[step[1]] = self._columns[step[2]]
                elif kind == _CANDIDATE:
                    w[step[1]] = candidate[step[2]]
                elif kind == _CONST:
                    w[step[1]] = step[2]
                else:
                    self._store(out, step[1], w[step[2]], M, N)

    def _store(self, out: np.ndarray, k: int, value, M: int, N: int) -> None:
        """Output entry k: the sum over samples of a value that may be constant along either axis."""
        value = np.asarray(value)
        if value.ndim == 0:
            out[:, k] = N * value
        elif value.shape[1] == N:
            out[:, k] = value.sum(axis=1)  # (1, N), data only: the same sum for every candidate
        else:
            out[:, k] = N * value[:, 0]  # (M, 1), candidate only


class ArrayValues(ArraySum):
    """``f(data_k, candidate)`` at every sample for many candidates, as NumPy array operations
    (built by :meth:`ArraySum.build`; the same program without the sum)."""

    summed = False

    def __call__(self, values: np.ndarray) -> np.ndarray:
        """Every sample's values for M candidates.

        Parameters
        ----------
        values : ndarray, shape (M, n_values)
            Each candidate's values (the non-data inputs of ``per_sample``, concatenated).

        Returns
        -------
        ndarray, shape (M, N, n_out)
        """
        return self._fill(values, np.empty((values.shape[0], self.n_samples, self.n_out)))

    def _store(self, out: np.ndarray, k: int, value, M: int, N: int) -> None:
        out[:, :, k] = value
