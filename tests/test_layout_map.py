"""The layout map (docs/explanation/layout.md) names every module of the package.

Truth: the package's files on disk; each module other than an ``__init__.py`` must appear in
the map by its file name in backticks, so a newcomer finds where it lives and what it holds.
"""

import pathlib

ROOT = pathlib.Path(__file__).resolve().parent.parent


def test_every_module_is_named_in_the_layout_map():
    page = (ROOT / "docs" / "explanation" / "layout.md").read_text(encoding="utf-8")
    modules = sorted(p for p in (ROOT / "casest").rglob("*.py") if p.name != "__init__.py")
    missing = [str(p.relative_to(ROOT)) for p in modules if f"`{p.name}`" not in page]
    assert not missing, f"name these in docs/explanation/layout.md: {missing}"
    assert "## Where a new piece goes" in page


def test_every_subpackage_ships_in_the_wheel():
    """pyproject.toml lists the packages explicitly (models/ and data/ ship under other names);
    a subpackage missing from the list is missing from the installed casest."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    packages = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "casest").rglob("__init__.py")}
    assert not packages - listed, f"add to [tool.setuptools] packages: {sorted(packages - listed)}"
