"""Reader for NIST StRD nonlinear-regression files, with a whitelist formula parser.

A NIST file holds the model formula in Fortran-like notation (``exp[...]``, ``**``,
``arctan[...]``), two starting points, certified values with certified standard
deviations, the certified residual sum of squares, and the data. :func:`read_nist`
turns one into a casest :class:`~casest.Model` plus the data and the certified figures.

The formula is parsed by a small recursive-descent parser that accepts only numbers,
the parameters ``b1..bK``, the predictors ``x`` / ``x1, x2, ...``, ``pi``, the operators
``+ - * / **``, parentheses and brackets, and the functions ``exp log sqrt sin cos tan
arctan``. Nothing from the file is ever passed to ``eval``.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .data import Dataset
from .model import LogUniform, Model, Parameter
from .sums import prediction_and_jacobian

__all__ = ["FormulaError", "parse_formula", "NistProblem", "read_nist", "nist_box"]


class FormulaError(ValueError):
    """A formula uses something outside the whitelist, or is malformed."""


_FUNCTIONS = {
    "exp": ca.exp,
    "log": ca.log,
    "sqrt": ca.sqrt,
    "sin": ca.sin,
    "cos": ca.cos,
    "tan": ca.tan,
    "arctan": ca.atan,
}
_CONSTANT_LINE = re.compile(r"^\s*([A-Za-z_]\w*)\s*=\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eEdD][-+]?\d+)?)\s*$")
_TOKEN = re.compile(r"\s*(?:(\d+\.\d*(?:[eEdD][+-]?\d+)?|\.\d+(?:[eEdD][+-]?\d+)?|\d+(?:[eEdD][+-]?\d+)?)|([A-Za-z_][A-Za-z_0-9]*)|(\*\*|[-+*/()\[\]]))")


def _tokens(text: str) -> list[tuple[str, str]]:
    out, pos = [], 0
    text = text.rstrip()
    while pos < len(text):
        match = _TOKEN.match(text, pos)
        if not match or match.end() == pos:
            raise FormulaError(f"character {text[pos:].strip()[:1]!r} at position {pos} of {text!r} is not allowed")
        number, name, op = match.groups()
        if number is not None:
            out.append(("num", number.replace("d", "e").replace("D", "e")))
        elif name is not None:
            out.append(("name", name))
        else:
            out.append(("op", op))
        pos = match.end()
    return out


class _Parser:
    """expr := term (('+'|'-') term)*; term := unary (('*'|'/') unary)*;
    unary := ('+'|'-') unary | power; power := atom ('**' unary)?;
    atom := number | name | func '[' expr ']' | func '(' expr ')' | '(' expr ')' | '[' expr ']'."""

    #: deepest nesting of brackets, unary signs and powers accepted (far above any real
    #: formula; deeper input would exhaust Python's recursion limit)
    MAX_DEPTH = 100

    def __init__(self, text: str, symbols: dict):
        self.text = text
        self.toks = _tokens(text)
        self.i = 0
        self.symbols = symbols
        self.used: set = set()
        self.depth = 0

    def _enter(self):
        self.depth += 1
        if self.depth > self.MAX_DEPTH:
            raise FormulaError(
                f"the formula nests brackets, signs or powers more than {self.MAX_DEPTH} deep: "
                f"{self.text[:60]!r}..."
            )

    def peek(self):
        return self.toks[self.i] if self.i < len(self.toks) else ("end", "")

    def take(self, kind=None, value=None):
        tok = self.peek()
        if (kind and tok[0] != kind) or (value and tok[1] != value):
            want = value or kind
            raise FormulaError(f"expected {want!r} but found {tok[1] or 'the end'!r} in {self.text!r}")
        self.i += 1
        return tok

    def parse(self):
        expr = self.expr()
        if self.peek()[0] != "end":
            raise FormulaError(f"unexpected {self.peek()[1]!r} in {self.text!r}")
        return expr

    def expr(self):
        value = self.term()
        while self.peek() in (("op", "+"), ("op", "-")):
            op = self.take()[1]
            rhs = self.term()
            value = value + rhs if op == "+" else value - rhs
        return value

    def term(self):
        value = self.unary()
        while self.peek() in (("op", "*"), ("op", "/")):
            op = self.take()[1]
            rhs = self.unary()
            value = value * rhs if op == "*" else value / rhs
        return value

    def unary(self):
        self._enter()
        try:
            if self.peek() in (("op", "+"), ("op", "-")):
                op = self.take()[1]
                value = self.unary()
                return -value if op == "-" else value
            return self.power()
        finally:
            self.depth -= 1

    def power(self):
        base = self.atom()
        if self.peek() == ("op", "**"):
            self.take()
            return base ** self.unary()
        return base

    def atom(self):
        kind, value = self.peek()
        if kind == "num":
            self.take()
            return float(value)
        if kind == "op" and value in "([":
            self.take()
            inner = self.expr()
            self.take("op", ")" if value == "(" else "]")
            return inner
        if kind == "name":
            self.take()
            lower = value.lower()
            if lower in _FUNCTIONS:
                opener = self.take("op")[1]
                if opener not in "([":
                    raise FormulaError(f"function {value!r} must be followed by '(' or '[' in {self.text!r}")
                arg = self.expr()
                self.take("op", ")" if opener == "(" else "]")
                return _FUNCTIONS[lower](arg)
            if value in self.symbols:
                self.used.add(value)
                return self.symbols[value]
            if lower == "pi":
                return math.pi
            raise FormulaError(
                f"name {value!r} in {self.text!r} is not allowed: only b1..bK, x/x1..xm, pi, "
                f"constants defined in the file and the functions {sorted(_FUNCTIONS)}"
            )
        raise FormulaError(f"unexpected {value or 'end of formula'!r} in {self.text!r}")


def parse_formula(text: str, symbols: dict):
    """Parse a NIST right-hand side into a CasADi expression of ``symbols`` (name -> SX).

    Raises
    ------
    FormulaError
        A character, name or function outside the whitelist, or a syntax error.
    """
    try:
        return _Parser(text, symbols).parse()
    except RecursionError:  # a caller already deep in its own stack
        raise FormulaError(f"the formula nests too deep to parse: {text[:60]!r}...") from None


@dataclass
class NistProblem:
    """One NIST StRD problem.

    Attributes
    ----------
    name : str
    formula : str
        The model as written in the file (``y = ...``).
    model : Model
        Parameters b1..bK (nominal = the chosen start, box from :func:`nist_box` on the
        parameters the separator finds nonlinear, none on the linear ones).
    data : Dataset
        Output ``y`` (or the transformed response, e.g. ``log[y]``), signals ``x``/``x1...``.
    start1, start2 : ndarray, shape (K,)
    certified : ndarray, shape (K,)
    certified_std : ndarray, shape (K,)
    certified_rss : float
    degrees_of_freedom : int
    linear : tuple of str
        Parameters the separator finds linear.
    start : {1, 2}
        The starting point used for the nominal values and the box.
    """

    name: str
    formula: str
    model: Model
    data: Dataset
    start1: np.ndarray
    start2: np.ndarray
    certified: np.ndarray
    certified_std: np.ndarray
    certified_rss: float
    degrees_of_freedom: int
    linear: tuple = field(default_factory=tuple)
    start: int = 1

    @property
    def start_values(self) -> np.ndarray:
        """The starting point the problem was read with (``start1`` or ``start2``), shape (K,)."""
        return self.start1 if self.start == 1 else self.start2

    def rss(self, theta) -> float:
        """Residual sum of squares of the model at ``theta``."""
        r = self.data.outputs - self.model.predict(theta, self.data.signals)
        return float(np.sum(r**2))


def nist_box(start: float) -> tuple[float, float]:
    """The protocol's box for a nonlinear parameter: sign(s1) [|s1|/1000, 1000 |s1|]."""
    if start == 0:
        return -1000.0, 1000.0
    lo, hi = abs(start) / 1000.0, abs(start) * 1000.0
    return (lo, hi) if start > 0 else (-hi, -lo)


def _block_lines(lines: list[str], label: str) -> tuple[int, int]:
    """Line range (1-based, inclusive) announced in the header, e.g. 'Data (lines 61 to 71)'."""
    for line in lines[:12]:
        m = re.search(label + r"\s*\(lines\s+(\d+)\s+to\s+(\d+)\)", line)
        if m:
            return int(m.group(1)), int(m.group(2))
    raise ValueError(f"header has no '{label} (lines A to B)' entry")


def read_nist(path: str | os.PathLike, start: int = 1) -> NistProblem:
    """Read a NIST StRD nonlinear-regression file into a :class:`NistProblem`.

    Parameters
    ----------
    path : str or path-like
    start : {1, 2}
        Which of the file's starting points gives the nominal values and the
        :func:`nist_box` of the nonlinear parameters.

    Raises
    ------
    FormulaError
        The model formula is outside the parser's whitelist or malformed.
    ValueError
        The file's layout is not a NIST StRD nonlinear-regression file.
    """
    if start not in (1, 2):
        raise ValueError(f"start must be 1 or 2 (the NIST files give two starting points), got {start!r}")
    from .separate import separate

    path = os.fspath(path)
    with open(path, encoding="utf-8", errors="replace") as fh:
        lines = fh.read().splitlines()
    name = os.path.splitext(os.path.basename(path))[0]
    p_first, p_last = _block_lines(lines, "Starting Values")
    d_first, d_last = _block_lines(lines, "Data")
    n_par = p_last - p_first + 1

    # the formula: from the line after "N Parameters (...)" to the start-value header
    model_at = next(i for i, line in enumerate(lines) if line.startswith("Model:"))
    par_at = next(i for i in range(model_at, p_first) if re.search(r"Parameters?\s*\(", lines[i]))
    text_lines = []
    for line in lines[par_at + 1 : p_first - 1]:
        if re.search(r"Starting\s+values", line, re.I):
            break
        if line.strip():
            text_lines.append(line.strip())
    # lines "name = number" before or after the model define constants (Roszman1: pi = 3.14...)
    constants, formula_lines = {}, []
    for line in text_lines:
        m = _CONSTANT_LINE.match(line)
        if m and not re.fullmatch(r"b\d+", m.group(1)):
            constants[m.group(1)] = float(m.group(2).replace("d", "e").replace("D", "e"))
        else:
            formula_lines.append(line)
    formula = " ".join(formula_lines)
    formula = re.sub(r"\+\s*e\s*$", "", formula).strip()
    if "=" not in formula:
        raise FormulaError(f"{name}: no '=' in the model formula {formula!r}")
    lhs, rhs = (part.strip() for part in formula.split("=", 1))

    start1, start2, cert, cert_std = [], [], [], []
    for line in lines[p_first - 1 : p_last]:
        m = re.match(r"\s*b(\d+)\s*=\s*(\S+)\s+(\S+)\s+(\S+)\s+(\S+)", line)
        if not m:
            raise ValueError(f"{name}: cannot read parameter line {line!r}")
        start1.append(float(m.group(2)))
        start2.append(float(m.group(3)))
        cert.append(float(m.group(4)))
        cert_std.append(float(m.group(5)))
    tail = "\n".join(lines[p_last : p_last + 8])
    rss = float(re.search(r"Residual Sum of Squares:\s*(\S+)", tail).group(1))
    dof = int(re.search(r"Degrees of Freedom:\s*(\d+)", tail).group(1))

    header = lines[d_first - 2].split(":", 1)[-1].split() if d_first >= 2 else []
    table = np.array([[float(v) for v in line.split()] for line in lines[d_first - 1 : d_last] if line.strip()])
    columns = header if len(header) == table.shape[1] else ["y"] + [f"x{i}" for i in range(1, table.shape[1])]
    predictors = columns[1:]

    symbols = dict(constants)
    symbols.update({f"b{i + 1}": ca.SX.sym(f"b{i + 1}") for i in range(n_par)})
    symbols.update({p: ca.SX.sym(p) for p in predictors})
    rhs_expr = parse_formula(rhs, symbols)
    response = columns[0]
    y = table[:, 0]
    if lhs.replace(" ", "") != response:
        # a transformed response, e.g. log[y] (Nelson): apply it to the data
        y_sym = ca.SX.sym(response)
        transform = parse_formula(lhs, {response: y_sym})
        y = np.array(ca.Function("lhs", [y_sym], [transform]).map(len(y))(y[None, :])).ravel()

    nominal = start1 if start == 1 else start2
    provisional = Model(
        [Parameter(f"b{i + 1}", nominal=nominal[i]) for i in range(n_par)],
        predictors,
        {"y": rhs_expr},
        name=name,
    )
    part = separate(provisional)
    params = []
    for i in range(n_par):
        pname = f"b{i + 1}"
        if pname in part.nonlinear:
            lo, hi = nist_box(nominal[i])
            params.append(Parameter(pname, lo, hi, nominal[i], prior=LogUniform() if lo * hi > 0 else None))
        else:
            params.append(Parameter(pname, nominal=nominal[i]))
    model = Model(params, predictors, {"y": rhs_expr}, name=name if start == 1 else f"{name} (start 2)")
    cols = {p: table[:, j + 1] for j, p in enumerate(predictors)}
    cols["y"] = y
    data = Dataset(model, cols)
    return NistProblem(
        name=name,
        formula=f"{lhs} = {rhs}",
        model=model,
        data=data,
        start1=np.array(start1),
        start2=np.array(start2),
        certified=np.array(cert),
        certified_std=np.array(cert_std),
        certified_rss=rss,
        degrees_of_freedom=dof,
        linear=part.linear,
        start=start,
    )


def log_relative_error(value: np.ndarray, reference: np.ndarray, cap: float = 11.0) -> np.ndarray:
    """NIST's LRE: -log10(|value - reference| / |reference|), capped (the certified digits)."""
    value, reference = np.asarray(value, dtype=float), np.asarray(reference, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.abs(value - reference) / np.where(reference != 0, np.abs(reference), 1.0)
        lre = -np.log10(err)
    lre = np.where(np.isnan(value), 0.0, lre)
    return np.clip(np.nan_to_num(lre, posinf=cap, nan=0.0), 0.0, cap)


def solve_protocol(problem: NistProblem, sweep_settings=None, solver_settings=None):
    """The suite's protocol: the problem's start as nominal, the :func:`nist_box` on nonlinear
    parameters, casest's two stages, Gauss-Newton covariance with the dof correction.

    Returns
    -------
    Estimate
    """
    import warnings

    from .pipeline import estimate

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return estimate(
            problem.model,
            problem.data,
            covariance="gauss-newton-dof",
            sweep_settings=sweep_settings,
            solver_settings=solver_settings,
        )


def scipy_least_squares(problem: NistProblem, jacobian: str = "2-point"):
    """``scipy.optimize.least_squares`` (trf) from the problem's start with the same bounds.

    Parameters
    ----------
    jacobian : {"2-point", "analytic"}
        Finite differences, or the exact Jacobian from CasADi.

    Returns
    -------
    theta : ndarray, shape (K,)
    std : ndarray, shape (K,)
        Gauss-Newton with the dof correction (NIST's convention).
    result : scipy.optimize.OptimizeResult
    """
    from scipy.optimize import least_squares

    model, data = problem.model, problem.data
    N = data.n_samples
    f = model.function.map(N)
    X = data.signals.T
    y = data.outputs[:, 0]

    def residual(theta):
        return np.asarray(f(X, theta)).ravel() - y

    def jac(theta):
        return prediction_and_jacobian(model, data.signals, theta)[1]

    res = least_squares(
        residual,
        problem.start_values,
        jac=jac if jacobian == "analytic" else "2-point",
        bounds=(model.lower_bounds, model.upper_bounds),
        method="trf",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
        max_nfev=10000,
    )
    J = jac(res.x)
    s2 = np.sum(res.fun**2) / (N - len(res.x))
    try:
        std = np.sqrt(np.diag(s2 * np.linalg.inv(J.T @ J)))
    except np.linalg.LinAlgError:
        std = np.full(len(res.x), np.nan)
    return res.x, std, res
