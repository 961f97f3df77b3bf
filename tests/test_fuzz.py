"""Fuzz the command line with mutated CSV files and model declarations (Hypothesis, derandomized).

Every run ends in a correct result, an honest "did not converge", or a user error with exit 2,
never a traceback, never exit 3, and never "trust it" beside an estimate farther than
fuzz_inputs.TRUST_K std from the simulated truth (see tests/fuzz_inputs.py). The longer
campaign is ``python3 scripts/campaigns/fuzz_inputs.py --examples 1000``.
"""

import casest
from hypothesis import HealthCheck, given, settings

from casest.apps.cli import main as cli
from fuzz_inputs import base_rows, mutations, run_case

scalar1 = casest.load_model_file("scalar1")
HEADER, ROWS = base_rows(scalar1.simulate)


@settings(max_examples=200, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(muts=mutations())
def test_mutated_inputs_end_in_a_result_or_a_user_error(muts, tmp_path, capsys):
    def captured():
        c = capsys.readouterr()
        return c.out, c.err

    run_case(cli, captured, str(tmp_path), HEADER, ROWS, muts)
