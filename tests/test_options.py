"""Option kinds declared once (casest.options) and the command line's cheap paths.

Truths: the Literal types' values are the ones each API accepts (a value outside is an
OptionError naming the option and the values); `casest models` and `casest --help` run without
importing the estimators (casest.estimation, casest.state), checked in a fresh interpreter.
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
            "heavy = [m for m in ('casest.estimation', 'casest.state', 'casest.design') if m in sys.modules]\n"
            "print('HEAVY', heavy)" % (arguments,))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert "HEAVY []" in out.stdout, out.stdout[-500:] + out.stderr[-500:]
