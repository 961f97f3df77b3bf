"""Every Python snippet of README.md and of the tutorial and how-to pages in docs/ runs, each page
on its own (its snippets in order, in a fresh process, from a temporary folder): a page imports
and defines what it uses, so a reader can run any page without the others."""

import pytest

import os
import re
import subprocess
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: README and the pages with code (each runs alone)
PAGES = ["README.md", "docs/tutorials/quickstart.md", "docs/tutorials/command-line.md",
         "docs/tutorials/model-files.md", "docs/tutorials/running-estimates.md", "docs/howto/data-files.md",
         "docs/howto/units.md", "docs/howto/experiments.md", "docs/howto/noise-models.md",
         "docs/explanation/pipeline.md", "docs/validation/paper-examples.md", "docs/tutorials/pitot.md",
         "docs/howto/embedding.md", "docs/validation/nist.md", "docs/validation/coverage.md", "docs/tutorials/appendix-b.md",
         "docs/tutorials/dynamic-models.md", "docs/tutorials/state-estimation.md",
         "docs/tutorials/experiment-design.md", "docs/howto/dask.md", "docs/tutorials/ampyx-ap2.md",
         "docs/howto/equation-error.md", "docs/howto/c-export.md"]


def _blocks(page):
    text = open(os.path.join(REPO, page), encoding="utf-8").read()
    return re.findall(r"```python\n(.*?)```", text, re.S)


def test_every_tutorial_page_is_listed():
    docs = {os.path.join(d, f) for d in ("docs/tutorials", "docs/howto") for f in os.listdir(os.path.join(REPO, d))
            if f.endswith(".md")}
    assert docs <= set(PAGES), sorted(docs - set(PAGES))


@pytest.mark.parametrize("page", [p for p in PAGES if _blocks(p)])
def test_each_page_runs_on_its_own(page, tmp_path):
    script = tmp_path / "page.py"
    script.write_text("\n\n".join(_blocks(page)))
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, f"{page}: " + proc.stderr[-3000:]
    if page == "README.md":
        assert len(_blocks(page)) == 1 and (tmp_path / "estimate.json").exists()


def test_the_pages_hold_enough_code():
    assert sum(len(_blocks(page)) for page in PAGES) >= 15
