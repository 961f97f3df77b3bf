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
import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..backend.sums import prediction_and_jacobian
from ..data.dataset import Dataset
from ..errors import FormulaError, OptionError
from ..models import LogUniform, Model, Parameter
from ..two_stage.symmetry import in_labels_of


__all__ = ["FormulaError", "parse_formula", "NistProblem", "read_nist", "nist_box", "protocol_report"]

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


def _block_lines(lines: list[str], label: str, name: str) -> tuple[int, int]:
    """Line range (1-based, inclusive) announced in the header, e.g. 'Data (lines 61 to 71)'."""
    for line in lines[:12]:
        m = re.search(label + r"\s*\(lines\s+(\d+)\s+to\s+(\d+)\)", line)
        if m:
            first, last = int(m.group(1)), int(m.group(2))
            if not 1 <= first <= last <= len(lines):
                raise FormulaError(f"{name}: the header announces {label} at lines {first} to {last}, but the file has "
                                   f"{len(lines)} lines (cut off?); use a complete NIST StRD file")
            return first, last
    raise FormulaError(f"{name}: the header has no '{label} (lines A to B)' entry; this is not a NIST StRD "
                       "nonlinear-regression file")


def _read_formula(lines: list[str], first_parameter_line: int, name: str) -> tuple[str, str, dict]:
    """The model formula's two sides and the constants defined beside it (Roszman1: pi = 3.14...)."""
    model_at = next((i for i, line in enumerate(lines) if line.startswith("Model:")), None)
    par_at = None if model_at is None else next(
        (i for i in range(model_at, first_parameter_line) if re.search(r"Parameters?\s*\(", lines[i])), None)
    if par_at is None:
        raise FormulaError(f"{name}: no 'Model:' section with its 'N Parameters (...)' line before the starting "
                           "values; this is not a NIST StRD nonlinear-regression file")
    text_lines = []
    for line in lines[par_at + 1 : first_parameter_line - 1]:
        if re.search(r"Starting\s+values", line, re.I):
            break
        if line.strip():
            text_lines.append(line.strip())
    constants, formula_lines = {}, []
    for line in text_lines:
        m = _CONSTANT_LINE.match(line)
        if m and not re.fullmatch(r"b\d+", m.group(1)):
            constants[m.group(1)] = float(m.group(2).replace("d", "e").replace("D", "e"))
        else:
            formula_lines.append(line)
    formula = re.sub(r"\+\s*e\s*$", "", " ".join(formula_lines)).strip()
    if "=" not in formula:
        raise FormulaError(f"{name}: no '=' in the model formula {formula!r}")
    lhs, rhs = (part.strip() for part in formula.split("=", 1))
    return lhs, rhs, constants


def _read_parameter_block(lines: list[str], first: int, last: int, name: str) -> tuple[np.ndarray, ...]:
    """Columns of the parameter block: start 1, start 2, certified value, certified std; and
    the certified residual sum of squares and degrees of freedom that follow it."""
    rows = []
    for line in lines[first - 1 : last]:
        m = re.match(r"\s*b(\d+)\s*=\s*(\S+)\s+(\S+)\s+(\S+)\s+(\S+)", line)
        try:
            rows.append([float(m.group(k)) for k in (2, 3, 4, 5)])
        except (AttributeError, ValueError):
            raise FormulaError(f"{name}: cannot read parameter line {line!r} (expected 'bK = start1 start2 "
                               "certified std')") from None
    tail = "\n".join(lines[last : last + 8])
    rss = re.search(r"Residual Sum of Squares:\s*(\S+)", tail)
    dof = re.search(r"Degrees of Freedom:\s*(\d+)", tail)
    if rss is None or dof is None:
        raise FormulaError(f"{name}: no certified 'Residual Sum of Squares' and 'Degrees of Freedom' after the "
                           "parameters; use a complete NIST StRD file")
    start1, start2, cert, cert_std = np.array(rows).T
    return start1, start2, cert, cert_std, float(rss.group(1)), int(dof.group(1))


def _read_table(lines: list[str], first: int, last: int, name: str) -> tuple[list[str], np.ndarray]:
    """The data block's column names (response first) and values, shape (n, n_columns)."""
    header = lines[first - 2].split(":", 1)[-1].split() if first >= 2 else []
    try:
        table = np.array([[float(v) for v in line.split()] for line in lines[first - 1 : last] if line.strip()])
    except ValueError as err:
        raise FormulaError(f"{name}: the data block (lines {first} to {last}) holds a field that is not a number "
                           f"({err})") from None
    if table.ndim != 2 or table.shape[0] == 0 or table.shape[1] < 2:
        raise FormulaError(f"{name}: the data block (lines {first} to {last}) is not a table of a response and "
                           "at least one predictor")
    columns = header if len(header) == table.shape[1] else ["y"] + [f"x{i}" for i in range(1, table.shape[1])]
    return columns, table


def _nist_model(name: str, formula: tuple, columns: list[str], nominal, start: int) -> tuple[Model, np.ndarray, list]:
    """The casest model of the formula with the protocol's boxes on the nonlinear parameters,
    the transform of the response column (identity unless the left side transforms it),
    and the linear parameters."""
    from ..problem.separate import separate

    lhs, rhs, constants = formula
    predictors, response = columns[1:], columns[0]
    symbols = dict(constants)
    symbols.update({f"b{i + 1}": ca.SX.sym(f"b{i + 1}") for i in range(len(nominal))})
    symbols.update({p: ca.SX.sym(p) for p in predictors})
    rhs_expr = parse_formula(rhs, symbols)
    y_sym = ca.SX.sym(response)
    # a transformed response, e.g. log[y] (Nelson): applied to the data
    transform = y_sym if lhs.replace(" ", "") == response else parse_formula(lhs, {response: y_sym})
    provisional = Model([Parameter(f"b{i + 1}", nominal=v) for i, v in enumerate(nominal)], predictors,
                        {"y": rhs_expr}, name=name)
    part = separate(provisional)
    params = []
    for i, value in enumerate(nominal):
        pname = f"b{i + 1}"
        if pname in part.nonlinear:
            lo, hi = nist_box(value)
            params.append(Parameter(pname, lo, hi, value, prior=LogUniform() if lo * hi > 0 else None))
        else:
            params.append(Parameter(pname, nominal=value))
    model = Model(params, predictors, {"y": rhs_expr}, name=name if start == 1 else f"{name} (start 2)")
    return model, ca.Function("response", [y_sym], [transform]), part.linear


def read_nist(path: str | os.PathLike, start: int = 1) -> NistProblem:
    """Read a NIST StRD nonlinear-regression file into a :class:`NistProblem`.

    Parameters
    ----------
    path : str or path-like
    start : {1, 2}
        Which of the file's starting points gives the nominal values and the
        :func:`nist_box` of the nonlinear parameters.

    Returns
    -------
    NistProblem
        The model (the formula, with the protocol's boxes), the data, the two starting
        points and the certified values, std, RSS and degrees of freedom.

    Raises
    ------
    FormulaError
        The file is not a NIST StRD nonlinear-regression file (a header entry, the formula,
        a parameter line or the certified figures missing, or the file cut off), or its
        formula is outside the parser's whitelist or malformed.
    OptionError
        ``start`` is neither 1 nor 2.
    """
    if start not in (1, 2):
        raise OptionError(f"start must be 1 or 2 (the NIST files give two starting points), got {start!r}")
    path = os.fspath(path)
    with open(path, encoding="utf-8", errors="replace") as fh:
        lines = fh.read().splitlines()
    name = os.path.splitext(os.path.basename(path))[0]
    p_first, p_last = _block_lines(lines, "Starting Values", name)
    d_first, d_last = _block_lines(lines, "Data", name)
    formula = _read_formula(lines, p_first, name)
    start1, start2, cert, cert_std, rss, dof = _read_parameter_block(lines, p_first, p_last, name)
    columns, table = _read_table(lines, d_first, d_last, name)
    model, response, linear = _nist_model(name, formula, columns, start1 if start == 1 else start2, start)
    cols = {p: table[:, j + 1] for j, p in enumerate(columns[1:])}
    cols["y"] = np.array(response.map(table.shape[0])(table[:, 0][None, :])).ravel()
    return NistProblem(
        name=name,
        formula=f"{formula[0]} = {formula[1]}",
        model=model,
        data=Dataset(model, cols),
        start1=start1,
        start2=start2,
        certified=cert,
        certified_std=cert_std,
        certified_rss=rss,
        degrees_of_freedom=dof,
        linear=linear,
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


def solve_protocol(problem: NistProblem, sweep_settings=None, solver_settings=None, mode: str = "auto"):
    """The suite's protocol: the problem's start as nominal, the :func:`nist_box` on nonlinear
    parameters, casest's two stages, Gauss-Newton covariance with the dof correction.

    Parameters
    ----------
    problem : NistProblem
    sweep_settings, solver_settings : optional
        As :func:`casest.estimate` takes them.
    mode : str
        Stage 2's mode (:func:`casest.estimate`'s ``mode``).

    Returns
    -------
    Estimate
    """
    import warnings

    from ..two_stage.pipeline import estimate

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return estimate(
            problem.model,
            problem.data,
            covariance="gauss-newton",
            dof_correction=True,
            sweep_settings=sweep_settings,
            solver_settings=solver_settings,
            mode=mode,
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


# ----------------------------------------------------------------------------- the protocol's report
def protocol_report(files, starts, separable: bool = True) -> bool:
    """Print the NIST protocol table (``casest nist``): casest and SciPy on every problem and start.

    Parameters
    ----------
    files : sequence of str
        NIST StRD ``.dat`` files.
    starts : sequence of int
        NIST's starts (1, 2).
    separable : bool
        Also the BOD, Puromycin and Osborne 1 table against their published optima.

    Returns
    -------
    bool
        Every problem solved to >= 6 correct digits in every parameter.
    """
    head = (f"{'problem':<12} {'K':>2} {'xi2':>3} | {'casest digits':>13} {'std digits':>10} {'RSS ratio':>12} {'s':>6} | "
            f"{'scipy-fd dig':>12} {'std':>5} {'s':>6} | {'scipy-an dig':>12} {'std':>5} {'s':>6}")
    print(head)
    print("-" * len(head))
    rows, names = [], []
    for path, start in [(p, s) for p in files for s in starts]:
        pr = read_nist(path, start=start)
        out = _nist_row(pr)
        names.append(f"{pr.name}/{start}")
        rows.append(out)
        print(f"{names[-1]:<12} {out[0]:>2} {out[1]:>3} | {out[2]:>13.1f} {out[3]:>10.1f} {out[4]:>12.9f} {out[5]:>6.2f} | "
              f"{out[6]:>12.1f} {out[7]:>5.1f} {out[8]:>6.2f} | {out[9]:>12.1f} {out[10]:>5.1f} {out[11]:>6.2f}", flush=True)
    table = np.array(rows, dtype=float)
    ok, std_ok = table[:, 2] >= 6, table[:, 3] >= 3
    print("-" * len(head))
    for start in starts:
        mine = np.array([n.endswith(f"/{start}") for n in names])
        print(f"casest from start {start}: {ok[mine].sum()}/{mine.sum()} problems with >= 6 correct digits in every "
              f"parameter, {std_ok[mine].sum()}/{mine.sum()} with >= 3 digits in every std; "
              f"total {table[mine, 5].sum():.1f} s")
    for k, name in ((6, "scipy least_squares, finite differences"), (9, "scipy least_squares, analytic Jacobian")):
        print(f"{name}: {(table[:, k] >= 6).sum()}/{len(table)} with >= 6 digits, "
              f"{(table[:, k + 1] >= 3).sum()}/{len(table)} std >= 3 digits; total {table[:, k + 2].sum():.1f} s")
    if separable:
        _separable_table()
    return bool(ok.all())



def _nist_row(pr) -> list:
    """K, n_xi2, then digits of the estimate and of the std, RSS ratio and seconds of casest, and
    digits and seconds of SciPy with finite differences and with the analytic Jacobian."""
    t = time.perf_counter()
    est = solve_protocol(pr)
    t_casest = time.perf_counter() - t
    theta, std = in_labels_of(pr.model, pr.data.signals, est.theta, est.std, pr.certified)  # NIST's labels
    out = [len(pr.certified), len(pr.certified) - len(pr.linear), log_relative_error(theta, pr.certified).min(),
           log_relative_error(std, pr.certified_std).min(), pr.rss(est.theta) / pr.certified_rss, t_casest]
    for jac in ("2-point", "analytic"):
        t = time.perf_counter()
        theta, std, _ = scipy_least_squares(pr, jac)
        out += [log_relative_error(theta, pr.certified).min(), log_relative_error(std, pr.certified_std).min(),
                time.perf_counter() - t]
    return out


def _separable_table() -> None:
    """BOD, Puromycin (treated) and Osborne 1 against their published optima, casest and SciPy."""
    from scipy.optimize import least_squares

    from ..models.modelfile import load_model_file

    module = load_model_file("separable")
    print()
    print(f"{'data set':<10} | {'casest RSS':>14} {'s':>6} | {'scipy-fd RSS':>14} {'s':>6} | {'published RSS':>13}")
    for name in module.PROBLEMS:
        t = time.perf_counter()
        _, rss = module.solve(name)
        t_c = time.perf_counter() - t
        model, data = module.PROBLEMS[name]()
        f = model.function.map(data.n_samples)
        t = time.perf_counter()
        res = least_squares(lambda th: np.asarray(f(data.signals.T, th)).ravel() - data.outputs[:, 0], model.nominal,
                            bounds=(model.lower_bounds, model.upper_bounds), method="trf", xtol=1e-15, ftol=1e-15,
                            gtol=1e-15)
        t_s = time.perf_counter() - t
        print(f"{name:<10} | {rss:>14.7g} {t_c:>6.2f} | {2 * res.cost:>14.7g} {t_s:>6.2f} | "
              f"{module.PUBLISHED[name]['rss']:>13g}")
