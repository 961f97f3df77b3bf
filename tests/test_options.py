"""Option kinds declared once (casest.options) and the command line's cheap paths.

Truths: the Literal types' values are the ones each API accepts (a value outside is an
OptionError naming the option and the values); `casest models` and `casest --help` run without
importing the estimators (casest.estimation, casest.filters), checked in a fresh interpreter.
"""

import subprocess
import sys

import pytest

import casest
from casest import options


def test_a_value_outside_its_kind_is_named():
    with pytest.raises(casest.OptionError, match=r"formulation must be one of \('time-varying', 'steady-state', "
                                                  r"'innovation'\), got 'practice'"):
        options.check_option("formulation", "practice", options.FilterErrorFormulation)
    options.check_option("mode", "reduced", options.Mode)  # no error
    assert options.choices(options.OperatingPoint) == ("first", "mean")


def test_the_apis_validate_through_the_kinds():
    with pytest.raises(casest.OptionError, match="least_squares_solver must be one of"):
        casest.SolverSettings(least_squares_solver="trf")
    with pytest.raises(casest.OptionError, match="integrator must be one of"):
        casest.DynamicModel([casest.Parameter("a", 0, 1, 0.5)], [casest.State("x", 0.0)], [], {"x": 0},
                            {"y": 0}, integrator="euler")


@pytest.mark.parametrize("arguments", [["models"], ["--help"]])
def test_listing_and_help_do_not_import_the_estimators(arguments):
    code = ("import sys\nfrom casest.apps.cli import main\ntry:\n    main(%r)\nexcept SystemExit:\n    pass\n"
            "heavy = [m for m in ('casest.estimation', 'casest.filters', 'casest.design') if m in sys.modules]\n"
            "print('HEAVY', heavy)" % (arguments,))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert "HEAVY []" in out.stdout, out.stdout[-500:] + out.stderr[-500:]


def test_casest_exports_each_name_once():
    assert len(casest.__all__) == len(set(casest.__all__))
    assert all(hasattr(casest, name) for name in casest.__all__)


@pytest.mark.parametrize("options, message", [
    ({"covariance": "hessain"}, r"covariance must be one of \('hessian'"),
    ({"mode": "fast"}, r"mode must be one of \('auto', 'paper'"),
    ({"solver_settings": {"max_iter": 3}}, "solver_settings must be a casest.SolverSettings"),
    ({"sweep_settings": 100}, "sweep_settings must be a casest.SweepSettings"),
    ({"max_starts": 0}, "max_starts must be an integer >= 1"),
    ({"covariance": "hessian-dof"}, r"covariance must be one of \('hessian', 'gauss-newton'\)"),
    ({"dof_correction": "yes"}, "dof_correction must be True or False"),
])
def test_estimate_refuses_a_misspelt_option_before_any_work(options, message, monkeypatch):
    """The options are checked before the problem is built or stage 1 runs (neither is reached)."""
    from casest.two_stage import pipeline

    def reached(*args, **kwargs):
        raise AssertionError("the estimate started work before checking its options")

    monkeypatch.setattr(pipeline, "_problem_of", reached)
    monkeypatch.setattr(pipeline, "sweep", reached)
    m = casest.load_model_file("scalar2")
    with pytest.raises(casest.OptionError, match=message):
        casest.estimate(m.model(), m.simulate(seed=0), **options)


def test_the_flat_module_paths_of_before_the_subpackages_are_gone():
    """No import finder for pre-release paths: ``casest.stage1`` is not a module (its content is
    ``casest.two_stage.sweep``)."""
    import importlib

    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("casest.stage1")
    assert not any(type(f).__module__.startswith("casest") for f in sys.meta_path)


def test_every_filter_error_formulation_has_its_strategy():
    """A string chooses an implementation through one registry: each formulation the option kind
    declares has exactly one entry."""
    from casest.filter_error.estimator import FORMULATIONS

    assert tuple(FORMULATIONS) == options.choices(options.FilterErrorFormulation) or \
        set(FORMULATIONS) == set(options.choices(options.FilterErrorFormulation))


def test_every_criterion_and_design_has_its_strategy():
    """The design criteria and stage 1's designs are chosen through registries too: one entry per
    value of the option kind (``"auto"`` resolves to one of the designs)."""
    from casest.design.criteria import CRITERION_TERMS
    from casest.two_stage.sweep.candidates import DESIGNS

    assert set(CRITERION_TERMS) == set(options.choices(options.Criterion))
    assert set(DESIGNS) | {"auto"} == set(options.choices(options.SweepDesign))
    with pytest.raises(casest.OptionError, match=r"SweepSettings.design must be one of \('auto', 'grid'"):
        casest.SweepSettings(design="latin")


def test_the_covariance_takes_the_users_solver_settings(monkeypatch):
    """The exact Hessian's sums are built with the estimate's own settings (threads, compilation),
    not a default SolverSettings()."""
    from casest.problem.problem import Problem

    seen = []
    original = Problem.cost_hessian

    def spy(self, threads, jit, flags):
        seen.append((threads, jit, tuple(flags)))
        return original(self, threads, jit, flags)

    monkeypatch.setattr(Problem, "cost_hessian", spy)
    m = casest.load_model_file("scalar2")
    settings = casest.SolverSettings(threads=1, jit=False, jit_flags=("-O1",))
    casest.estimate(m.model(), m.simulate(seed=0), solver_settings=settings)
    assert seen and seen[-1] == (1, False, ("-O1",))


def test_the_degrees_of_freedom_correction_is_its_own_option(scalar1):
    """covariance names the information matrix, dof_correction the factor N m / (N m - p) on it
    (analytic: the same estimate, its covariance scaled by exactly that factor; scalar example 1,
    N = 100 samples, m = 1 output, p = 3 parameters)."""
    import numpy as np

    model, data = scalar1.model(), scalar1.simulate(3)
    for information in ("hessian", "gauss-newton"):
        plain = casest.estimate(model, data, covariance=information)
        corrected = casest.estimate(model, data, covariance=information, dof_correction=True)
        np.testing.assert_allclose(corrected.theta, plain.theta, rtol=1e-12)
        np.testing.assert_allclose(corrected.covariance, plain.covariance * 100 / (100 - 3), rtol=1e-10)
        assert corrected.covariance_method == information and corrected.dof_correction
        assert "degrees-of-freedom corrected" in corrected.report()
        loaded = casest.Estimate.from_json(corrected.to_json())
        assert loaded.dof_correction and loaded.covariance_method == information


def test_every_public_option_is_annotated_with_its_kind():
    """A parameter of a public function or constructor with a string default is an option: its
    annotation is its Literal kind from casest.options (free-text names and the fields of result
    records excepted), so the signature says what it takes."""
    import importlib
    import inspect

    results = (casest.Estimate, casest.FilterErrorEstimate, casest.FrequencyEstimate, casest.Regression,
               casest.Stage2Result)
    free_text = {"name", "unit", "time", "title", "where", "label", "prefix", "path", "order", "model_name"}
    modules = ["casest", "casest.filters", "casest.filter_error", "casest.recursive", "casest.export", "casest.interop",
               "casest.design",
               "casest.estimation", "casest.two_stage", "casest.two_stage.sweep", "casest.equation_error",
               "casest.frequency", "casest.models", "casest.problem", "casest.data", "casest.backend"]
    seen, loose = set(), []
    for module_name in modules:
        module = importlib.import_module(module_name)
        for name in module.__all__:
            obj = getattr(module, name)
            if id(obj) in seen or obj in results:
                continue  # a result's fields record what was done; they are not options
            seen.add(id(obj))
            if inspect.isclass(obj):
                calls = [obj.__init__] + [v for k, v in vars(obj).items() if inspect.isfunction(v) and k[0] != "_"]
            else:
                calls = [obj] if inspect.isfunction(obj) else []
            for call in calls:
                for p in inspect.signature(call).parameters.values():
                    if isinstance(p.default, str) and p.name not in free_text \
                            and str(p.annotation) not in options.__all__ and "Literal" not in str(p.annotation):
                        loose.append(f"{module_name}.{name}({p.name}: {p.annotation})")
    assert len(seen) > 100  # the public API was walked at all
    assert not loose, loose
