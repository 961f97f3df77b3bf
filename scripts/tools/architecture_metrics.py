"""Structure of the casest package, for the architecture's before/after comparisons.

    python3 scripts/tools/architecture_metrics.py [PATH_OF_A_CHECKOUT]   # default: this checkout

Prints the number of modules, the largest ones, the functions over 80 lines, the functions
of cyclomatic complexity above 25 (needs ``pip install radon``), the lines that branch on a
model's type and the comparisons of a noise label.
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
NOISE_LABEL = re.compile(r"noise_kind\s*[=!]=|noise_model\.startswith|kind\s*==\s*\"(known|full|diagonal)\"")


def main(root: pathlib.Path) -> None:
    package = root / "casest"
    files = sorted(package.rglob("*.py"))
    sizes = sorted(((f.read_text().count("\n"), str(f.relative_to(root))) for f in files), reverse=True)
    long_functions, type_branches, noise_labels = [], [], []
    for f in files:
        text = f.read_text()
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno + 1 > 80:
                long_functions.append(f"{f.relative_to(root)}:{node.name} ({node.end_lineno - node.lineno + 1})")
        for i, line in enumerate(text.splitlines(), 1):
            if line.strip().startswith("#") or "def " in line:
                continue
            if TYPE_BRANCH.search(line):
                type_branches.append(f"{f.relative_to(root)}:{i}")
            if NOISE_LABEL.search(line):
                noise_labels.append(f"{f.relative_to(root)}:{i}")
    print(f"modules: {len(files)}; largest: {', '.join(f'{p} ({n})' for n, p in sizes[:3])}")
    print(f"modules over 600 lines: {[p for n, p in sizes if n > 600]}")
    print(f"functions over 80 lines: {len(long_functions)} {long_functions}")
    if shutil.which("radon"):
        out = subprocess.run(["radon", "cc", "-s", "-n", "D", str(package)], capture_output=True, text=True).stdout
        high = [line.strip() for line in out.splitlines()
                if (m := re.search(r"\((\d+)\)", line)) and int(m.group(1)) > 25]
        print(f"complexity above 25: {len(high)} {high}")
    else:
        print("complexity above 25: radon is not installed (pip install radon)")
    print(f"type branches: {len(type_branches)}")
    for where in type_branches:
        print(f"  {where}")
    print(f"noise-label comparisons: {len(noise_labels)} {noise_labels}")


if __name__ == "__main__":
    main(pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else pathlib.Path(__file__).resolve().parents[2]))
