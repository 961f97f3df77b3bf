"""Every repository path that README.md and the docs name exists (files move; links must follow).

Paths are the backticked or plain mentions that start with a top-level folder of the project
(casest/, scripts/, tests/, models/, data/, docs/, .ci/); the Sphinx build folder is made by the
docs build and is not checked.
"""

import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
PATH = re.compile(r"(?<![\w/.-])((?:casest|scripts|tests|models|data|docs|\.ci)/[\w./-]*[\w/])")
GENERATED = ("docs/_build", "docs/auto_examples", "docs/api/generated")


def named_paths():
    pages = [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md")) + sorted((ROOT / "docs").rglob("*.rst"))
    for page in pages:
        relative = page.relative_to(ROOT).as_posix()
        if relative.startswith(GENERATED):
            continue
        for match in PATH.finditer(page.read_text(encoding="utf-8")):
            path = match.group(1).rstrip(".")
            if not path.startswith(GENERATED):
                yield relative, path


def test_every_path_named_in_the_docs_exists():
    paths = list(named_paths())
    assert len(paths) > 100  # the pattern finds the docs' paths at all
    missing = [(page, path) for page, path in paths if not (ROOT / path).exists()]
    assert not missing, missing
