"""The figures of the shared-machinery review, measured on this checkout.

    python3 scripts/tools/seam_metrics.py            # static and runtime figures (about 30 s warm)
    python3 scripts/tools/seam_metrics.py --static   # the static figures only (no estimate runs)
    python3 scripts/tools/seam_metrics.py --complexity PACKAGE_DIR ...   # the complexity figures of any package

Static (read from the source of ``casest/``):

- the result types and how many implement :class:`casest.EstimateLike`;
- ``casadi.nlpsol`` sites whose options do not come from ``SolverSettings``
  (``nlpsol_options()`` / ``sqpmethod_options()``);
- inline checks of a noise covariance ``R`` outside ``checks.py``: ``if``/``elif``/``assert``/``return``
  lines that compare an ``R...`` name with 0 or test ``isfinite(R...)``;
- comparisons against string literals (``==``/``!=``/``in`` with a ``str`` constant or a tuple of them);
- total cyclomatic complexity per 1,000 source lines (radon's SLOC) and how many functions sit at
  CC 1-5, 6-10, 11-15 and above 15, and the largest (needs ``pip install radon``).

Runtime (counted with ``sys.setprofile`` on warm calls of the bundled models):

- calls of ``measurement_of`` per warm static estimate (``models/scalar2.py``) and of
  ``Dataset.check_model`` per dynamic estimate (``models/short_period.py``);
- calls of ``check_option`` per static estimate;
- the modules of ``casest`` that a filter-error estimate (``models/longitudinal.py``) runs code in,
  and how often its call path returns to a module it left: distinct (A, B) with a stack
  ``... A ... B ... A`` (A called into B, which called back into A);
- the time until ``estimate(..., covariance="hessain")`` raises.
"""

from __future__ import annotations

import argparse
import ast
import os
import pathlib
import re
import shutil
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[2]
R_CHECK = re.compile(r"\bR\w*\s*(<=|<|>|>=)\s*0(\.0)?\b|isfinite\(\s*R\b|\bR\w*\.min\(\)\s*(<=|<)")


def _sources():
    return sorted((ROOT / "casest").rglob("*.py"))


def nlpsol_sites() -> list:
    """``nlpsol`` calls whose options argument does not come from SolverSettings."""
    loose = []
    for path in _sources():
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "nlpsol"
                    and len(node.args) >= 3):
                text = ast.unparse(node)
                if "_options(" not in text and not _options_variable(tree, node):
                    loose.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    return loose


def _options_variable(tree, call) -> bool:
    """Whether the options argument is a name assigned from ``settings.*_options()`` in the same function."""
    if len(call.args) < 4 or not isinstance(call.args[3], ast.Name):
        return False
    name = call.args[3].id
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(isinstance(t, (ast.Name, ast.Attribute)) and
                                                ast.unparse(t).endswith(name) for t in node.targets):
            if "_options(" in ast.unparse(node.value):
                return True
    return False


def inline_r_checks() -> list:
    out = []
    for path in _sources():
        if path.name == "checks.py":
            continue
        for i, line in enumerate(path.read_text().splitlines(), 1):
            code = line.split("#")[0]
            if re.search(r"^\s*(if|elif|assert|return)\b", code) and R_CHECK.search(code):
                out.append(f"{path.relative_to(ROOT)}:{i}")
    return out


def string_comparisons() -> int:
    count = 0
    for path in _sources():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare):
                operands = [node.left, *node.comparators]
                if any(_is_str(o) for o in operands):
                    count += 1
    return count


def _is_str(node) -> bool:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return True
    return isinstance(node, (ast.Tuple, ast.List, ast.Set)) and bool(node.elts) and all(_is_str(e) for e in node.elts)


def complexity(package: pathlib.Path | None = None) -> str:
    """Total cyclomatic complexity of the functions and methods of ``package`` (default ``casest/``) per
    1,000 source lines (radon's SLOC), how many functions sit at CC 1-5, 6-10, 11-15 and above 15,
    and the largest."""
    if not shutil.which("radon"):
        return "complexity: radon is not installed (pip install radon)"
    package = package or ROOT / "casest"
    out = subprocess.run(["radon", "cc", "-s", "-a", str(package)], capture_output=True, text=True).stdout
    # functions and methods (F, M); a class's line repeats its methods' complexity
    found = [(int(m.group(2)), m.group(1)) for m in re.finditer(r"^\s+[FM] \d+:\d+ (\S+) - [A-F] \((\d+)\)", out, re.M)]
    scores = [score for score, _ in found]
    raw = subprocess.run(["radon", "raw", "-s", str(package)], capture_output=True, text=True).stdout
    sloc = int(re.findall(r"^\s+SLOC: (\d+)", raw, re.M)[-1])
    bands = [sum(1 for s in scores if low <= s <= high) for low, high in ((1, 5), (6, 10), (11, 15), (16, 10**9))]
    largest = max(found, default=(0, "-"))
    return (f"complexity: {sum(scores)} in {sloc} source lines = {1000 * sum(scores) / sloc:.0f} per 1,000; "
            f"{len(scores)} functions: {bands[0]} at CC 1-5, {bands[1]} at 6-10, {bands[2]} at 11-15, "
            f"{bands[3]} above 15; largest {largest[1]} ({largest[0]})")


def result_types() -> str:
    import casest
    from casest.equation_error import Stepwise
    from casest.estimation import EstimateLike

    types = [casest.Estimate, casest.FilterErrorEstimate, casest.FrequencyEstimate, casest.Regression, Stepwise]
    names = [t.__name__ for t in types]
    members = [m for m in EstimateLike.__protocol_attrs__ if not m.startswith("_")] \
        if hasattr(EstimateLike, "__protocol_attrs__") else [m for m in dir(EstimateLike) if not m.startswith("_")]
    missing = {t.__name__: [m for m in members if not hasattr(t, m) and m not in getattr(t, "__dataclass_fields__", {})]
               for t in types}
    complete = [n for n, miss in missing.items() if not miss]
    return f"result types: {len(types)} ({', '.join(names)}); implementing EstimateLike: {len(complete)}"


class _Counter:
    """Counts calls of the given functions' code objects while active."""

    def __init__(self, *functions):
        self.codes = {f.__code__: f.__qualname__ for f in functions}
        self.counts = {name: 0 for name in self.codes.values()}

    def __call__(self, frame, event, arg):
        if event == "call" and frame.f_code in self.codes:
            self.counts[self.codes[frame.f_code]] += 1

    def run(self, work):
        sys.setprofile(self)
        try:
            work()
        finally:
            sys.setprofile(None)
        return self.counts


class _Path:
    """The casest modules entered, and the (A, B) pairs where B called back into A."""

    def __init__(self):
        self.stack, self.modules, self.returns = [], set(), set()

    def __call__(self, frame, event, arg):
        if event == "call":
            module = frame.f_globals.get("__name__", "")
            self.stack.append(module if module.startswith("casest") else None)
            if module.startswith("casest"):
                self.modules.add(module)
                chain = [m for m in self.stack[:-1] if m]
                if chain and chain[-1] != module and module in chain:
                    self.returns.add((module, chain[-1]))
        elif event == "return" and self.stack:
            self.stack.pop()


def runtime() -> list:
    import warnings

    import numpy as np

    import casest
    from casest.data.dataset import Dataset
    from casest.options import check_option
    from casest.problem.measurement import measurement_of

    warnings.simplefilter("ignore")
    lines = []
    scalar = casest.load_model_file(str(ROOT / "models" / "scalar2.py"))
    data = scalar.simulate(seed=1)
    model = scalar.model()
    casest.estimate(model, data)  # warm
    fresh = scalar.simulate(seed=1)  # a record not seen before, as a user's next estimate has
    counts = _Counter(measurement_of, check_option).run(lambda: casest.estimate(model, fresh))
    lines.append(f"measurement_of per warm static estimate: {counts['measurement_of']}; "
                 f"check_option per static estimate: {counts['check_option']}")
    short = casest.load_model_file(str(ROOT / "models" / "short_period.py"))
    dmodel, ddata = short.model(), short.simulate(seed=1)
    casest.estimate(dmodel, ddata)
    fresh = short.simulate(seed=1)
    counts = _Counter(Dataset.check_model, measurement_of).run(lambda: casest.estimate(dmodel, fresh))
    lines.append(f"Dataset.check_model per dynamic estimate: {counts['Dataset.check_model']}; "
                 f"measurement_of: {counts['measurement_of']}")
    longitudinal = casest.load_model_file(str(ROOT / "models" / "longitudinal.py"))
    fmodel, fdata = longitudinal.model(), longitudinal.simulate(seed=1)
    process = {"u": 0.1, "w": 0.1}  # the model file's own start (its main())
    casest.filter_error_estimate(fmodel, fdata, process)
    path = _Path()
    sys.setprofile(path)
    try:
        casest.filter_error_estimate(fmodel, fdata, process)
    finally:
        sys.setprofile(None)
    lines.append(f"filter-error estimate: {len(path.modules)} casest modules entered; its path returns to a module "
                 f"it left {len(path.returns)} times")
    start = time.perf_counter()
    try:
        casest.estimate(model, data, covariance="hessain")
    except casest.CasestError as error:
        lines.append(f"covariance='hessain': {type(error).__name__} after {1e3 * (time.perf_counter() - start):.1f} ms")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--static", action="store_true", help="the static figures only")
    parser.add_argument("--complexity", nargs="+", metavar="PACKAGE",
                        help="only the complexity figures of these package folders (another codebase measured alike)")
    args = parser.parse_args()
    if args.complexity:
        for package in args.complexity:
            print(f"{package}: {complexity(pathlib.Path(package))}")
        return
    sys.path.insert(0, str(ROOT))
    print(result_types())
    loose = nlpsol_sites()
    print(f"nlpsol sites not taking SolverSettings: {len(loose)} {loose}")
    checks = inline_r_checks()
    print(f"inline R checks outside checks.py: {len(checks)} {checks}")
    print(f"string-literal comparisons in casest/: {string_comparisons()}")
    print(complexity())
    if not args.static:
        for line in runtime():
            print(line)


if __name__ == "__main__":
    main()
