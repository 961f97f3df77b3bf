#!/usr/bin/env python3
"""Run the test suite in random orders: every test must pass whatever ran before it.

    python3 scripts/tools/random_order.py [--seeds 1 2 3] [-- PYTEST ARGS]

Needs the `dev` extra (`pip install -e ".[dev]"`: pytest-randomly). Each seed shuffles the
modules, the classes and the tests within them; a failure prints the seed that reproduces it
(`python3 -m pytest -p randomly -p no:cacheprovider --randomly-seed=SEED`). The default test
run (`python3 -m pytest -q`, `.ci/run`) keeps the files' order: pytest-randomly is not in the
`test` extra.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys

REPO = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1], help="random orders to run (pytest-randomly seeds)")
    parser.add_argument("pytest_args", nargs="*", help="further pytest arguments (after --)")
    args = parser.parse_args(argv)
    if importlib.util.find_spec("pytest_randomly") is None:
        print("pytest-randomly is not installed: pip install -e '.[dev]'", file=sys.stderr)
        return 2
    failed = []
    for seed in args.seeds:
        command = [sys.executable, "-m", "pytest", "-q", "-p", "randomly", "-p", "no:cacheprovider",
                   f"--randomly-seed={seed}", *args.pytest_args]
        print(f"seed {seed}: {' '.join(command[1:])}", flush=True)
        if subprocess.run(command, cwd=REPO).returncode != 0:
            failed.append(seed)
    print("every order passed" if not failed else f"failed with seeds {failed}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
