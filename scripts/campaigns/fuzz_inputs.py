"""The longer fuzz campaign of tests/test_fuzz.py: mutated CSV files and model declarations
through ``casest solve``, with the count of each outcome.

    python3 scripts/campaigns/fuzz_inputs.py [--examples 1000] [--seed 0]
    python3 scripts/campaigns/fuzz_inputs.py --apis [--examples 1000]   (tests/test_fuzz_apis.py, longer)

Every run must end in a result (exit 0 or 4; a "trust it" within fuzz_inputs.TRUST_K std of
the truth), an honest "did not converge" (exit 1) or a user error (exit 2, one or two lines),
never a traceback or exit 3. A broken rule stops the campaign with the mutations that broke it.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import io
import os
import sys
import tempfile
import warnings

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(REPO, "tests"))

import casest  # noqa: E402
from hypothesis import HealthCheck, given, seed, settings  # noqa: E402

from casest.apps.cli import main as cli  # noqa: E402
from fuzz_inputs import base_rows, mutations, run_case, summary_key  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--examples", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--apis", action="store_true", help="fuzz the newer entry points (filters, smoothers, "
                        "recursive ML, joint filter, delays, result files, MAT paths) instead of the command line")
    args = parser.parse_args()
    if args.apis:
        import subprocess

        env = {**os.environ, "CASEST_FUZZ_EXAMPLES": str(args.examples)}
        sys.exit(subprocess.call([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                                  os.path.join(REPO, "tests", "test_fuzz_apis.py")], env=env))
    header, rows = base_rows(casest.load_model_file("scalar1").simulate)
    counts: collections.Counter = collections.Counter()
    kinds: collections.Counter = collections.Counter()
    folder = tempfile.mkdtemp(prefix="casest_fuzz_")

    @seed(args.seed)
    @settings(max_examples=args.examples, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(muts=mutations())
    def campaign(muts):
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            status = run_case(cli, lambda: (out.getvalue(), err.getvalue()), folder, header, rows, muts)
        counts[summary_key(status, out.getvalue())] += 1
        kinds.update(kind for kind, _ in muts)

    campaign()
    print(f"{sum(counts.values())} mutated inputs (seed {args.seed}); outcomes:")
    for key, n in counts.most_common():
        print(f"  {key}: {n}")
    print("mutations drawn:", dict(kinds.most_common()))


if __name__ == "__main__":
    main()
