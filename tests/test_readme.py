"""Every Python snippet of README.md and of the tutorial and how-to pages in docs/ runs (in the
order below, in one namespace, from a temporary folder): the pages that were the README's
sections stay executable."""

import os
import re
import subprocess
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: README first, then the pages in the order the former README had them (later snippets use
#: names defined by earlier ones)
PAGES = ["README.md", "docs/tutorials/quickstart.md", "docs/tutorials/command-line.md",
         "docs/tutorials/model-files.md", "docs/tutorials/running-estimates.md", "docs/howto/data-files.md",
         "docs/howto/units.md", "docs/howto/experiments.md", "docs/howto/noise-models.md",
         "docs/explanation/pipeline.md", "docs/validation/paper-examples.md", "docs/tutorials/pitot.md",
         "docs/howto/embedding.md", "docs/validation/nist.md", "docs/validation/coverage.md", "docs/tutorials/appendix-b.md",
         "docs/tutorials/dynamic-models.md", "docs/tutorials/state-estimation.md",
         "docs/tutorials/experiment-design.md", "docs/howto/dask.md", "docs/tutorials/ampyx-ap2.md",
         "docs/howto/equation-error.md"]


def _blocks(page):
    text = open(os.path.join(REPO, page), encoding="utf-8").read()
    return re.findall(r"```python\n(.*?)```", text, re.S)


def test_every_tutorial_page_is_listed():
    docs = {os.path.join(d, f) for d in ("docs/tutorials", "docs/howto") for f in os.listdir(os.path.join(REPO, d))
            if f.endswith(".md")}
    assert docs <= set(PAGES), sorted(docs - set(PAGES))


def test_readme_and_docs_python_snippets_run(tmp_path):
    blocks = [block for page in PAGES for block in _blocks(page)]
    assert len(_blocks("README.md")) == 1 and len(blocks) >= 15
    script = tmp_path / "readme_snippets.py"
    script.write_text("\n\n".join(blocks))
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "estimate.json").exists()
