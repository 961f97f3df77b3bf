"""Structure of the casest package, for the architecture's before/after comparisons.

    python3 scripts/tools/architecture_metrics.py [PATH_OF_A_CHECKOUT]   # default: this checkout

Prints the number of modules, the largest ones, the functions over 80 lines of code (docstrings,
blank and comment lines not counted), the largest function, the functions of cyclomatic
complexity above 25 and those above 10 per 1000 lines of code (needs ``pip install radon``; the
total decision density and the spread of complexity are in ``seam_metrics.py``), the lines that branch on a model's type, on a noise flag or
capability (``full_noise``, ``noise.full``, ``noise.estimated``, ``per_channel``), on the
removed noise keywords still accepted (parameters of ``solve_stage2`` and ``parameter_uncertainty``
of those names), and the comparisons of a noise label.
"""

from __future__ import annotations

import ast
import pathlib
import re
import shutil
import subprocess
import sys

TYPE_BRANCH = re.compile(r"isinstance\([^)]*\b(DynamicModel|Model)\b|\b(self|problem)\.dynamic\b|\.simulated\b"
                         r"|^\s*dynamic = isinstance|\bif dynamic\b|\bdynamic else\b")
NOISE_FLAG = re.compile(r"\bfull_noise\b|noise\.full\b|\.estimated\b|\.(profiled_)?per_channel\b|\.takes_mask\b")
#: the removed noise keywords of each function that took them (``Problem.known_R`` is a current property)
LEGACY_KEYWORDS = {"solve_stage2": {"known_R", "prior_penalty", "full_R"},
                   "parameter_uncertainty": {"r_known", "R_full", "prior_precision"}}
BRANCH = re.compile(r"^\s*(if|elif|while)\b|\bif\b.*\belse\b|\b(and|or)\b")
NOISE_LABEL = re.compile(r"noise_kind\s*[=!]=|noise_model\.startswith|kind\s*==\s*\"(known|full|diagonal)\"")


def main(root: pathlib.Path) -> None:
    package = root / "casest"
    files = sorted(package.rglob("*.py"))
    sizes = sorted(((f.read_text().count("\n"), str(f.relative_to(root))) for f in files), reverse=True)
    long_functions, type_branches, noise_labels, noise_flags, legacy_flags = [], [], [], [], []
    largest = (0, "")
    for f in files:
        text = f.read_text()
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = code_lines(node, text)
                largest = max(largest, (length, f"{f.relative_to(root)}:{node.name}"))
                if length > 80:
                    long_functions.append(f"{f.relative_to(root)}:{node.name} ({length})")
                arguments = node.args.posonlyargs + node.args.args + node.args.kwonlyargs
                legacy_flags += [f"{f.relative_to(root)}:{node.name}({a.arg})" for a in arguments
                                 if a.arg in LEGACY_KEYWORDS.get(node.name, ())]
        for i, line in enumerate(text.splitlines(), 1):
            if line.strip().startswith("#") or "def " in line:
                continue
            where = f"{f.relative_to(root)}:{i}"
            if TYPE_BRANCH.search(line):
                type_branches.append(where)
            if NOISE_LABEL.search(line):
                noise_labels.append(where)
            code = line.split("#")[0]
            if BRANCH.search(code) and NOISE_FLAG.search(code):
                noise_flags.append(where)
    print(f"modules: {len(files)}; largest: {', '.join(f'{p} ({n})' for n, p in sizes[:3])}")
    print(f"modules over 600 lines: {[p for n, p in sizes if n > 600]}")
    print(f"functions over 80 lines: {len(long_functions)} {long_functions}; largest: {largest[1]} ({largest[0]})")
    if shutil.which("radon"):
        out = subprocess.run(["radon", "cc", "-s", "-n", "D", str(package)], capture_output=True, text=True).stdout
        high = [line.strip() for line in out.splitlines()
                if (m := re.search(r"\((\d+)\)", line)) and int(m.group(1)) > 25]
        print(f"complexity above 25: {len(high)} {high}")
        print(_density(package))
    else:
        print("complexity above 25: radon is not installed (pip install radon)")
    print(f"type branches: {len(type_branches)}")
    for where in type_branches:
        print(f"  {where}")
    print(f"noise-label comparisons: {len(noise_labels)} {noise_labels}")
    print(f"branches on a noise flag or capability: {len(noise_flags)}")
    for where in noise_flags:
        print(f"  {where}")
    print(f"removed noise keywords still accepted: {len(legacy_flags)}")
    for where in legacy_flags:
        print(f"  {where}")


def code_lines(node: ast.AST, text: str) -> int:
    """A function's lines of code: its lines without its docstring, blank lines and comment lines
    (a long docstring is documentation, never a reason to cut a function)."""
    lines = text.splitlines()[node.lineno - 1:node.end_lineno]
    body = node.body
    if body and isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None), ast.Constant) \
            and isinstance(body[0].value.value, str):
        first, last = body[0].lineno - node.lineno, body[0].end_lineno - node.lineno
        lines = lines[:first] + lines[last + 1:]
    return sum(1 for line in lines if line.strip() and not line.strip().startswith("#"))


def _density(package: pathlib.Path) -> str:
    """Functions of cyclomatic complexity above 10 (radon grades C-F) per 1000 lines of code."""
    cc = subprocess.run(["radon", "cc", "-s", "-n", "C", str(package)], capture_output=True, text=True).stdout
    above = sum(1 for line in cc.splitlines() if re.search(r" - [C-F] \(\d+\)", line))
    raw = subprocess.run(["radon", "raw", "-s", str(package)], capture_output=True, text=True).stdout
    loc = int(re.findall(r"^\s+LOC: (\d+)", raw, re.M)[-1])
    return f"complexity above 10: {above} functions in {loc} lines of code, {1000 * above / loc:.2f} per 1000 lines"


if __name__ == "__main__":
    main(pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else pathlib.Path(__file__).resolve().parents[2]))
