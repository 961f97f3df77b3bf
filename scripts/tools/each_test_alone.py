#!/usr/bin/env python3
"""Run every test alone, each in a fresh Python process: no test may depend on another having run.

    python3 scripts/tools/each_test_alone.py [--workers 2] [--out each_test_alone.txt] [-- PYTEST ARGS]

Collects the test ids (``pytest --collect-only``, with the further pytest arguments, e.g.
``-m "not slow"`` or a file), then runs ``pytest ID`` for each in its own process, ``--workers``
at a time. Every finished test is appended to ``--out`` (``passed``/``FAILED`` and the id), so
an interrupted run resumes where it stopped; the failures are printed at the end with the
command that reproduces each. Exit status 1 when a test fails alone.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import os
import subprocess
import sys
import time

REPO = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")


def collect(pytest_args: list) -> list:
    """The test ids pytest collects with these arguments."""
    done = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:randomly",
                           "-p", "no:cacheprovider", *pytest_args], cwd=REPO, capture_output=True, text=True)
    ids = [line.strip() for line in done.stdout.splitlines() if "::" in line and not line.startswith(" ")]
    if not ids:
        raise SystemExit(f"no test collected:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    return ids


def run_alone(test_id: str) -> tuple:
    """``(test id, passed, seconds, the output's tail)`` of one test in a fresh process."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:randomly", "-p", "no:cacheprovider",
                           test_id], cwd=REPO, capture_output=True, text=True)
    return test_id, done.returncode == 0, time.perf_counter() - t0, (done.stdout + done.stderr)[-3000:]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--workers", type=int, default=2, help="tests run at once (processes)")
    parser.add_argument("--out", default="each_test_alone.txt", help="the record of finished tests (resumes from it)")
    parser.add_argument("pytest_args", nargs="*", help="further pytest arguments (after --)")
    args = parser.parse_args(argv)
    ids = collect(args.pytest_args)
    finished = {}
    if os.path.exists(args.out):
        with open(args.out, encoding="utf-8") as fh:
            finished = dict(reversed(line.rstrip("\n").split(" ", 1)) for line in fh if " " in line)
    todo = [i for i in ids if i not in finished]
    print(f"{len(ids)} tests, {len(ids) - len(todo)} already run alone, {len(todo)} to run", flush=True)
    t0 = time.perf_counter()
    with open(args.out, "a", encoding="utf-8") as record, \
            concurrent.futures.ThreadPoolExecutor(max_workers=max(1, args.workers)) as pool:
        for k, (test_id, passed, seconds, tail) in enumerate(pool.map(run_alone, todo), 1):
            finished[test_id] = "passed" if passed else "FAILED"
            record.write(f"{finished[test_id]} {test_id}\n")
            record.flush()
            if not passed:
                print(f"FAILED alone: {test_id}\n{tail}", flush=True)
            if k % 50 == 0:
                print(f"{k}/{len(todo)} in {time.perf_counter() - t0:.0f} s", flush=True)
    failed = [i for i in ids if finished.get(i) == "FAILED"]
    print(f"{len(ids) - len(failed)} of {len(ids)} tests pass alone ({time.perf_counter() - t0:.0f} s this run)")
    for test_id in failed:
        print(f"  FAILED: python3 -m pytest -p no:randomly '{test_id}'")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
