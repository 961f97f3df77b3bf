"""Where the data can inform a nonlinear parameter: ranges read from the model's structure.

A parameter that enters a static model only as a shift of a signal (``x - b``: a peak's
centre, a breakpoint, a delay) changes the fit only while the shifted signal's features lie
inside the record: beyond the signal's range its term is a tail. A rate (``b * x``) or a
scale (``x / b``, ``(x - c)^2 / b^2``) of a signal matters between the record's finest
spacing and its span: a decay a hundred times faster than the sampling, or a width a hundred
times the record, looks like a spike or a constant. A box spanning six decades around such
parameters (NIST's protocol box, say) puts nearly all of stage 1's candidates where the data
say nothing, and the basin of a multi-peak optimum can hold none of them.

:func:`informative_box` reads these roles from the model's CasADi expression graph
(every use of the parameter must have the same role on the same signal) and gives each such
parameter its informative range inside its box; :func:`draw_informative` draws stage-1
candidates there (uniform in a shift, log-uniform in a rate or a scale). The pipeline uses
them for a second look when the first estimate's residuals fail their tests
(:mod:`casest.two_stage.focused`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

__all__ = ["SignalRole", "InformativeBox", "signal_roles", "informative_box", "draw_informative",
           "RANGE_MARGIN", "NARROWER_THAN", "CENTRAL_SHARE", "ROLE_RULES", "PASSING", "SQUARED"]

#: how far beyond the record's finest spacing and its span a rate or a scale stays informative
RANGE_MARGIN = 10.0
#: a parameter's informative range counts as narrower than its box when the central part of the
#: range (:data:`CENTRAL_SHARE` of it, in the metric candidates are drawn in there) holds less than
#: this share of the box's sampling prior times CENTRAL_SHARE: the first sweep then put most
#: candidates where the data say little (a centre drawn log-uniformly over six decades lands mostly
#: near the record's start, even where half of the prior lies inside the record)
NARROWER_THAN = 0.5
#: the central part of an informative range, as a share of it (linear for a shift, logarithmic
#: for a rate or a scale)
CENTRAL_SHARE = 0.8


@dataclass(frozen=True)
class SignalRole:
    """How one nonlinear parameter enters the model: ``kind`` is ``"shift"`` (``x - b``, or
    ``x + b`` with ``sign`` -1), ``"rate"`` (``b x``), ``"scale"`` (``x / b``),
    ``"rate2"`` (``b x^2``) or ``"scale2"`` (``x^2 / b``) of the signal ``signal``;
    ``centred`` says the signal enters shifted (``(x - c) / b``: its span, not its magnitude,
    sets the range)."""

    kind: str
    signal: str
    sign: int = 1
    centred: bool = False


@dataclass(frozen=True)
class InformativeBox:
    """The informative ranges of the swept parameters.

    Attributes
    ----------
    names : tuple of str, length n2
        The swept (nonlinear) parameters, in the partition's order.
    lower, upper : ndarray, shape (n2,)
        Each parameter's informative range inside its box (its box where it has no role).
    roles : tuple of (SignalRole or None), length n2
    narrowed : tuple of str
        The parameters whose range holds less than :data:`NARROWER_THAN` of their box's prior.
    """

    names: tuple
    lower: np.ndarray
    upper: np.ndarray
    roles: tuple
    narrowed: tuple

    def describe(self) -> str:
        """One phrase per narrowed parameter: ``"b4 in [1, 250] (a shift of x)"``."""
        words = {"shift": "a shift", "rate": "a rate", "scale": "a scale", "rate2": "a rate of the square",
                 "scale2": "a scale of the square"}
        parts = []
        for name in self.narrowed:
            j = self.names.index(name)
            role = self.roles[j]
            parts.append(f"{name} in [{self.lower[j]:.4g}, {self.upper[j]:.4g}] ({words[role.kind]} of {role.signal})")
        return ", ".join(parts)


# slot kinds while walking the instruction list
_PARAM, _PARAM_SQ, _SIGNAL, _SIGNAL_SQ = "param", "param_sq", "signal", "signal_sq"
# a use that only hands the parameter on (a negation, a copy, a square): its role is the next use's
_PASS = ("pass",)


def signal_roles(model, nonlinear_index) -> list:
    """The role of each swept parameter in a static model's outputs (None where it has none).

    Parameters
    ----------
    model : Model
        A static model (its ``x``, ``theta`` and ``h``).
    nonlinear_index : sequence of int
        Indices into ``model.theta`` of the swept parameters.

    Returns
    -------
    list of (SignalRole or None), one per swept parameter
    """
    fun = ca.Function("roles", [model.x, model.theta], [model.h], {"live_variables": False})
    kinds: dict = {}
    uses: dict = {int(i): [] for i in nonlinear_index}
    for k in range(fun.n_instructions()):
        op, ins, outs = fun.instruction_id(k), fun.instruction_input(k), fun.instruction_output(k)
        if op == ca.OP_INPUT:
            arg, nz = ins
            kinds[outs[0]] = (_SIGNAL, int(nz), False, 1) if arg == 0 else (_PARAM, int(nz), 1)
            continue
        if op == ca.OP_CONST:
            kinds[outs[0]] = ("const", float(fun.instruction_constant(k)))
            continue
        if op == ca.OP_OUTPUT:
            _use(uses, kinds.get(ins[0]), None)
            continue
        args = [kinds.get(i) for i in ins]
        result, roles = _combine(op, args)
        for arg, role in zip(args, roles):
            _use(uses, arg, role)
        if result is not None:
            kinds[outs[0]] = result
    names = model.signal_names
    out = []
    for i in nonlinear_index:
        found = uses[int(i)]
        if not found or any(r is None for r in found) or len(set(found)) != 1:
            out.append(None)
            continue
        kind, signal, sign, centred = found[0]
        out.append(SignalRole(kind, names[signal], sign, centred))
    return out


def _use(uses: dict, arg, role) -> None:
    """Record a use of a parameter slot (``role`` None: a use of no known role)."""
    if arg is not None and arg[0] in (_PARAM, _PARAM_SQ) and arg[1] in uses and role != _PASS:
        uses[arg[1]].append(role)


#: instructions that hand their one argument on unchanged: opcode -> the argument kinds they pass
PASSING = {ca.OP_NEG: (_SIGNAL, _SIGNAL_SQ), ca.OP_ASSIGN: (_SIGNAL, _SIGNAL_SQ, _PARAM, _PARAM_SQ)}
#: what squaring makes of a slot: its kind -> the squared kind
SQUARED = {_PARAM: _PARAM_SQ, _SIGNAL: _SIGNAL_SQ}
#: the roles of a parameter that meets a signal in a binary instruction:
#: (opcode, the signal's kind, the parameter's kind, the parameter's place, the role).
#: The place is ``"either"`` (a product: both orders) or ``"second"`` (the divisor).
ROLE_RULES = (
    (ca.OP_MUL, _SIGNAL, _PARAM, "either", "rate"),        # b x
    (ca.OP_MUL, _SIGNAL_SQ, _PARAM, "either", "rate2"),    # b x^2
    (ca.OP_MUL, _SIGNAL_SQ, _PARAM_SQ, "either", "rate"),  # b^2 x^2 = (b x)^2
    (ca.OP_DIV, _SIGNAL, _PARAM, "second", "scale"),       # x / b
    (ca.OP_DIV, _SIGNAL_SQ, _PARAM_SQ, "second", "scale"),  # x^2 / b^2 = (x / b)^2
    (ca.OP_DIV, _SIGNAL_SQ, _PARAM, "second", "scale2"),   # x^2 / b
)


def _combine(op: int, args: list) -> tuple:
    """(the kind of an instruction's result, the role of each argument's parameter use), by the
    tables above; a shift (``x - b``, ``x + b``) makes a shifted signal."""
    a = args[0] if args else None
    b = args[1] if len(args) > 1 else None
    kinds = (a[0] if a else None, b[0] if b else None)
    none = [None] * len(args)
    if op == ca.OP_NEG and kinds[0] == _PARAM:
        return (_PARAM, a[1], -a[2]), [_PASS]
    if kinds[0] in PASSING.get(op, ()):
        return a, [_PASS if kinds[0] in (_PARAM, _PARAM_SQ) else None]
    squared = op == ca.OP_SQ or (op == ca.OP_CONSTPOW and kinds[1] == "const" and b[1] == 2.0)
    if squared and kinds[0] in SQUARED:
        result = (_PARAM_SQ, a[1]) if kinds[0] == _PARAM else (_SIGNAL_SQ, a[1], a[2])
        return result, ([_PASS] if kinds[0] == _PARAM else [None]) + none[1:]
    if op in (ca.OP_ADD, ca.OP_SUB) and set(kinds) == {_SIGNAL, _PARAM}:
        return _shift(op, a, b)
    roles = _table_roles(op, a, b, kinds)
    return None, (roles if roles is not None else none)


def _table_roles(op: int, a, b, kinds: tuple) -> list | None:
    """The argument roles :data:`ROLE_RULES` gives a binary instruction, or None where no rule matches."""
    for rule_op, signal_kind, parameter_kind, place, role in ROLE_RULES:
        if op == rule_op and place == "either" and set(kinds) == {signal_kind, parameter_kind}:
            sig, par = (a, b) if kinds[0] == signal_kind else (b, a)
            return [(role, sig[1], 1, sig[2]) if x is par else None for x in (a, b)]
        if op == rule_op and place == "second" and kinds == (signal_kind, parameter_kind):
            return [None, (role, a[1], 1, a[2])]
    return None


def _shift(op: int, a: tuple, b: tuple) -> tuple:
    """A signal plus or minus a parameter: the shifted signal, and the parameter's shift role."""
    sig, par = (a, b) if a[0] == _SIGNAL else (b, a)
    if sig[2]:  # already shifted: a second shift is not a role of its own
        return None, [None, None]
    # s - p, p - s: zero at p = s (sign +1); s + p: zero at p = -s
    sign = par[2] * (1 if op == ca.OP_SUB else -1)
    role = ("shift", sig[1], sign, False)
    return (_SIGNAL, sig[1], True, 1), [role if x is par else None for x in (a, b)]


def _signal_extent(values: np.ndarray) -> tuple | None:
    """(min, max, largest magnitude, finest positive spacing) of a signal's finite values."""
    v = np.unique(values[np.isfinite(values)])
    if v.size < 2:
        return None
    return float(v[0]), float(v[-1]), float(np.max(np.abs(v))), float(np.min(np.diff(v)))


def _role_range(role: SignalRole, extent: tuple) -> tuple | None:
    """The informative range of one role (positive for rates and scales; None if it has none)."""
    low, high, magnitude, spacing = extent
    if role.kind == "shift":
        return (low, high) if role.sign > 0 else (-high, -low)
    length = (high - low) if role.centred else magnitude
    if not (length > 0 and spacing > 0):
        return None
    m = RANGE_MARGIN
    return {"rate": (1.0 / (m * length), m / spacing), "scale": (spacing / m, m * length),
            "rate2": (1.0 / (m * length) ** 2, (m / spacing) ** 2),
            "scale2": ((spacing / m) ** 2, (m * length) ** 2)}[role.kind]


def _central_part(role: SignalRole, a: float, b: float) -> tuple:
    """The central :data:`CENTRAL_SHARE` of the range [a, b]: linear for a shift, logarithmic for
    a rate or a scale of one sign."""
    trim = 0.5 * (1.0 - CENTRAL_SHARE)
    if role.kind == "shift" or a * b <= 0:
        return a + trim * (b - a), b - trim * (b - a)
    sign = 1.0 if a > 0 else -1.0
    la, lb = np.log(abs(a)), np.log(abs(b))
    ends = sorted(sign * np.exp(v) for v in (la + trim * (lb - la), lb - trim * (lb - la)))
    return float(ends[0]), float(ends[1])


def informative_box(model, partition, data) -> InformativeBox | None:
    """The informative ranges of a static model's swept parameters on a record.

    Parameters
    ----------
    model : Model
        A static model.
    partition : Partition
        Which parameters are swept (xi2).
    data : Dataset
        The record whose signals set the ranges.

    Returns
    -------
    InformativeBox or None
        None when no swept parameter's range is narrower than its box (or the model is not
        static, or has no swept parameters).
    """
    if not partition.n_nonlinear or not hasattr(model, "x") or getattr(model, "is_dynamic", False):
        return None
    index = list(partition.nonlinear_index)
    roles = signal_roles(model, index)
    lower, upper = model.lower_bounds[index].astype(float), model.upper_bounds[index].astype(float)
    lo, hi, narrowed = lower.copy(), upper.copy(), []
    for j, (i, role) in enumerate(zip(index, roles)):
        extent = None if role is None else _signal_extent(np.asarray(data.column(role.signal), dtype=float).ravel())
        span = None if extent is None else _role_range(role, extent)
        if span is None:
            continue
        a, b = span
        if role.kind != "shift" and upper[j] <= 0:  # a negative box: the same magnitudes, negative
            a, b = -b, -a
        elif role.kind != "shift" and lower[j] < 0:
            continue  # a rate or a scale whose box spans zero: no one range
        a, b = max(a, lower[j]), min(b, upper[j])
        if not a < b:
            continue
        lo[j], hi[j] = a, b
        param = model.parameters[i]
        prior = param.sampling_prior
        c, d = _central_part(role, a, b)
        mass = float(prior.cdf(np.array([d]), param.lb, param.ub)[0] - prior.cdf(np.array([c]), param.lb, param.ub)[0])
        if mass < NARROWER_THAN * CENTRAL_SHARE:
            narrowed.append(param.name)
    if not narrowed:
        return None
    return InformativeBox(tuple(partition.nonlinear), lo, hi, tuple(roles), tuple(narrowed))


def draw_informative(model, partition, box: InformativeBox, n_candidates: int, seed: int = 0) -> np.ndarray:
    """Stage-1 candidates in the informative ranges: uniform in a shift, log-uniform in a rate or
    a scale (their magnitudes span decades), through its prior over the box for a parameter
    without a role.

    Parameters
    ----------
    model : Model
    partition : Partition
    box : InformativeBox
    n_candidates : int
        Candidates to draw (rounded up to a power of two for the Sobol sequence, then cut).
    seed : int
        The scrambled Sobol sequence's seed.

    Returns
    -------
    ndarray, shape (n_candidates, n2)
        Physical units, inside the parameters' bounds.
    """
    from scipy.stats import qmc

    n2 = partition.n_nonlinear
    m = max(1, int(math.ceil(math.log2(max(2, n_candidates)))))
    u = qmc.Sobol(d=n2, scramble=True, seed=seed).random_base2(m)[:n_candidates]
    columns = []
    for j, i in enumerate(partition.nonlinear_index):
        role, lo, hi = box.roles[j], box.lower[j], box.upper[j]
        param = model.parameters[i]
        if role is None or (lo, hi) == (param.lb, param.ub):
            columns.append(param.sampling_prior.ppf(u[:, j], param.lb, param.ub))
        elif role.kind == "shift" or lo <= 0 <= hi:
            columns.append(lo + u[:, j] * (hi - lo))
        else:
            sign = 1.0 if lo > 0 else -1.0
            a, b = np.log(abs(lo)), np.log(abs(hi))
            columns.append(sign * np.exp(a + u[:, j] * (b - a)))
    return np.clip(np.column_stack(columns), model.lower_bounds[list(partition.nonlinear_index)],
                   model.upper_bounds[list(partition.nonlinear_index)])
