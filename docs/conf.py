"""Sphinx configuration of the casest documentation (build: see README, "Documentation")."""

import os
import sys
from datetime import date

sys.path.insert(0, os.path.abspath(".."))

import casest  # noqa: E402

project = "casest"
author = "the casest developers"
copyright = f"{date.today().year}, {author}"
version = release = casest.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "figures/README.md", "examples/README.txt"]
myst_heading_anchors = 3
suppress_warnings = ["myst.header"]  # pages moved from the README keep their heading levels

autosummary_generate = True
autodoc_default_options = {"members": False}
autodoc_inherit_docstrings = True  # an override without its own docstring shows the base method's
autodoc_typehints = "none"  # the numpydoc sections give the types
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_attributes_as_param_list = False

sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "abort_on_example_error": True,
    "download_all_examples": False,
    "remove_config_comments": True,
    "matplotlib_animations": False,
}

html_theme = "pydata_sphinx_theme"
html_title = f"casest {version}"
html_theme_options = {"navigation_with_keys": False, "show_toc_level": 2}
html_static_path = ["_static"]
html_css_files = ["casest.css"]  # long API names and example lines wrap at 1280 px
templates_path = ["_templates"]
