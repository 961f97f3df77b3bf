"""The API reference lists every public name, and every public function documents its
parameters and what it returns (numpydoc sections)."""

import importlib
import inspect
import os
import re

import pytest

import casest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SUBPACKAGES = ["casest.filters", "casest.filter_error", "casest.recursive", "casest.export", "casest.interop", "casest.design",
               "casest.estimation",
               "casest.two_stage", "casest.two_stage.sweep", "casest.equation_error", "casest.frequency",
               "casest.models", "casest.problem", "casest.data", "casest.backend", "casest.errors", "casest.status"]


def _reference_names() -> set:
    names = set()
    for page in ("index.rst", "subpackages.rst"):
        text = open(os.path.join(REPO, "docs", "api", page), encoding="utf-8").read()
        module = "casest"
        for line in text.splitlines():
            current = re.match(r"\.\. currentmodule:: (\S+)", line)
            if current:
                module = current.group(1)
            entry = re.match(r"   ([A-Za-z_][A-Za-z0-9_]*)$", line)
            if entry:
                names.add(f"{module}.{entry.group(1)}")
    return names


def _public():
    """(qualified name, object) of casest.__all__ and every subpackage's __all__ (each object once)."""
    seen = {}
    for module_name in ["casest"] + SUBPACKAGES:
        module = importlib.import_module(module_name)
        for name in module.__all__:
            obj = getattr(module, name)
            seen.setdefault(id(obj), (module_name, name, obj))
    return list(seen.values())


def test_every_public_name_is_in_the_api_reference():
    listed = _reference_names()
    missing = [f"{module}.{name}" for module, name, _ in _public()
               if f"{module}.{name}" not in listed and f"casest.{name}" not in listed]
    assert not missing, f"add to docs/api/index.rst or subpackages.rst: {missing}"


def _section(doc: str, title: str) -> bool:
    return re.search(rf"^\s*{title}\n\s*-{{3,}}\s*$", doc or "", re.M) is not None


def _functions():
    return [(f"{module}.{name}", obj) for module, name, obj in _public() if inspect.isfunction(obj)]


@pytest.mark.parametrize("name,function", _functions(), ids=[n for n, _ in _functions()])
def test_public_function_has_parameters_and_returns(name, function):
    doc = inspect.getdoc(function)
    takes = [p for p in inspect.signature(function).parameters if p not in ("self", "cls")]
    if takes:
        assert _section(doc, "Parameters"), f"{name}: no numpydoc Parameters section"
    assert _section(doc, "Returns") or _section(doc, "Yields"), f"{name}: no numpydoc Returns section"


ENTRY_POINTS = ["estimate", "Problem", "sweep", "solve_stage2", "DynamicModel", "KalmanFilter",
                "ExtendedKalmanFilter", "design_experiment"]


@pytest.mark.parametrize("name", ENTRY_POINTS + ["casest.interop.ml_problem", "casest.interop.add_to_opti",
                                                 "casest.interop.estimator_function"])
def test_main_entry_points_have_examples(name):
    module, _, attr = name.rpartition(".")
    obj = getattr(importlib.import_module(module or "casest"), attr)
    assert _section(inspect.getdoc(obj), "Examples"), f"{name}: no Examples section"


@pytest.mark.parametrize("name", ENTRY_POINTS + ["casest.interop.ml_problem", "casest.interop.add_to_opti",
                                                 "casest.interop.estimator_function"])
def test_examples_run(name, tmp_path, monkeypatch):
    """The Examples sections are doctests: they run and print what they show."""
    import doctest

    monkeypatch.chdir(tmp_path)
    module, _, attr = name.rpartition(".")
    obj = getattr(importlib.import_module(module or "casest"), attr)
    parser, runner = doctest.DocTestParser(), doctest.DocTestRunner(
        optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    test = parser.get_doctest(inspect.getdoc(obj), {}, name, None, 0)
    assert test.examples
    result = runner.run(test, out=lambda text: print(text, end=""))
    assert result.failed == 0


def _methods():
    out = []
    for module, name, obj in _public():
        if not inspect.isclass(obj):
            continue
        seen = set()
        for klass in obj.__mro__:  # with the methods of casest's own bases and mixins
            if not klass.__module__.startswith("casest"):
                continue
            for attr, member in vars(klass).items():
                function = member.__func__ if isinstance(member, (classmethod, staticmethod)) else member
                if not attr.startswith("_") and inspect.isfunction(function) and attr not in seen:
                    seen.add(attr)
                    out.append((f"{module}.{name}.{attr}", getattr(obj, attr)))
    return out


@pytest.mark.parametrize("name,method", _methods(), ids=[n for n, _ in _methods()])
def test_public_method_has_parameters_and_returns(name, method):
    """Methods of the exported classes; an override without a docstring of its own is documented
    by its base class's (as the API reference shows it)."""
    doc = inspect.getdoc(method)
    takes = [p for p in inspect.signature(method).parameters if p not in ("self", "cls")]
    if takes:
        assert _section(doc, "Parameters"), f"{name}: no numpydoc Parameters section"
    assert _section(doc, "Returns") or _section(doc, "Yields"), f"{name}: no numpydoc Returns section"
