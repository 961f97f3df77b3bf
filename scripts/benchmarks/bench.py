#!/usr/bin/env python3
"""Performance benchmarks, all in one process on the same data (ratios, not timed tests).

    python3 scripts/benchmarks/bench.py --check [--runs 7] [--beside N]   (re-measure the stated claims: claims.py check;
                                                               --beside: beside N CPU-bound processes)
    python3 scripts/benchmarks/bench.py [--quick] [--parts cold stage1 stage2 dynamic flight practice filters dask scaling illcond global streamed] [--out docs/benchmarks.md]

cold     Cold start on the Pitot default in fresh processes: import casest, the first estimate,
         an estimate with a fresh model object, a warm estimate, each with its C compiles, with an
         empty compile cache and with the cache the first process filled.

stage1   Stage-1 throughput (candidate x sample evaluations per second) on the Pitot model,
         N = 1e3, 1e4, 1e5 samples and K = 500, 5000 candidates: casest's sweep (uncompiled
         NumPy arrays and JIT) against a loop of one numpy.linalg.lstsq per candidate (A and b from the
         same CasADi functions); the sweep's peak RSS against N (fresh processes, up to
         N = 1e6); the share of the machine's dense BLAS
         rate (a matrix product measured here) that the batched least squares reach; and
         against the same sweep in vectorised NumPy and in JAX (jit of vmap), checked equal.
stage2   Time to solution and success of casest (full pipeline, and stage 2 alone from the
         same start; cold and warm) against scipy.optimize.least_squares (trf) and lmfit
         (leastsq, if installed), each with the exact Jacobian (NumPy, written by hand in
         scripts/benchmarks/stage2_peers.py and checked against casest's) and with finite differences,
         on scalar 2, the Pitot problem (plain LS and ML by per-channel reweighting for the
         peers; all judged by the ML cost) and the bundled NIST problems from both starts.
flight   scripts/benchmarks/bench_output_error.py: the bundled dynamic files with the Gauss-Newton and IPOPT
         output-error paths; the 38-parameter aircraft output error, cold and warm, both paths,
         against JAX + SciPy least_squares in the same run; filter-error ML on the 4-state
         longitudinal record in its three formulations and with both solvers.
practice scripts/benchmarks/bench_practice_filter_error.py: filter error's three formulations on the
         practice-size turbulent record (models/turbulent_longitudinal.py), CPU seconds cold and warm.
filters  scripts/benchmarks/bench_filters.py: the EKF over a 1e4-sample pendulum record, casest's compiled pass
         (cold and warm) and its step-by-step loop against filterpy and a JAX lax.scan EKF.
dynamic  Dynamic models: stage-1 candidate x sample rate through the ODE (data compatibility,
         N = 5000 samples, 4096 Sobol candidates of the six IMU biases; CasADi VM and compiled),
         and output-error stage 2 of the short-period model at N = 1e4 from the same start:
         cold (a fresh process: build, compile, solve) and warm (the next record in the same
         process), against a SciPy fit of the same problem (solve_ivp of the states and their
         sensitivities interval by interval, least_squares with that Jacobian, reweighted per
         channel to the ML fixed point).
dask     scripts/benchmarks/bench_dask_sweep.py: the Pitot sweep (N = 1e4, 20000 candidates) on a Dask
         LocalCluster of 1 and 2 worker processes against the local sweep, checked equal.
scaling  Stage-2 time per IPOPT iteration and peak memory on the Pitot model as N grows
         from 1e2 to 1e6 (longer records repeat the flight with fresh noise), with the
         fitted log-log slope.
illcond  scripts/benchmarks/bench_illconditioned.py: stage 1 with a 60-column ill-conditioned linear basis
         against a well-conditioned one of the same size.
global   scripts/benchmarks/global_peer.py: casest's pipeline against SciPy trf from Sobol starts with a
         stopping rule tuned on the global-optimum net, on the net and the 24 NIST rows.
streamed scripts/benchmarks/bench_streamed_sweep.py: the streamed sweep on a LocalCluster up to 1e7
         candidates (memory, equality with the local sweep, a killed worker, a resumed driver).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402

from bench_common import LINES, READING, cold_state, say  # noqa: E402
from bench_cold import bench_cold, bench_scaling, scaling_one  # noqa: E402
from bench_dynamic import bench_dynamic, output_error_one  # noqa: E402
from bench_stage1 import bench_stage1  # noqa: E402
from bench_stage2 import bench_stage2  # noqa: E402


def bench_flight_parts(quick: bool) -> None:
    """Flight-test practice on the dynamic half (scripts/benchmarks/bench_output_error.py): both output-error paths on
    the bundled dynamic files and on the 38-parameter aircraft against JAX + SciPy, and filter-error ML in
    both formulations."""
    import bench_output_error as boe

    say("## Output error and filter error (flight-test practice)")
    say()
    boe.bench_small(say)
    boe.bench_flight(skip_ipopt=quick, say=say)
    boe.bench_filter(say)


def bench_practice_part(quick: bool) -> None:
    """Filter error's three formulations on the practice-size turbulent record
    (scripts/benchmarks/bench_practice_filter_error.py), five fresh processes each (three with --quick)."""
    import bench_practice_filter_error

    bench_practice_filter_error.bench(3 if quick else 5, say)


def bench_illconditioned_part(quick: bool) -> None:
    """Stage 1 on an ill-conditioned linear basis against a well-conditioned one (scripts/benchmarks/bench_illconditioned.py)."""
    import bench_illconditioned

    say("## Stage 1 on an ill-conditioned basis (60 + 3 parameters, N = 2000)")
    say()
    bench_illconditioned.bench(500 if quick else 2000, 2, lambda line: (say(f"- {line}")))
    say()


def _distributed_installed() -> bool:
    """Whether dask.distributed is installed; if not, the section says so."""
    import importlib.util

    if importlib.util.find_spec("distributed") is None:
        say("Not measured: dask.distributed is not installed (`pip install casest[parallel]`).")
        say()
        return False
    return True


def bench_dask_part(quick: bool) -> None:
    """Stage 1 on a dask.distributed LocalCluster (scripts/benchmarks/bench_dask_sweep.py; needs casest[parallel])."""
    say("## Stage 1 on a Dask cluster")
    say()
    if not _distributed_installed():
        return
    import bench_dask_sweep

    bench_dask_sweep.bench(10000, 4000 if quick else 20000, 2000, say)


def bench_global_part(quick: bool) -> None:
    """casest's pipeline against a global peer (scripts/benchmarks/global_peer.py)."""
    import global_peer

    say("## The global pipeline against a global peer (SciPy multi-start)")
    say()
    say("SciPy `least_squares` (trf, exact Jacobian, the same box) from scrambled Sobol starts through the parameters' "
        "sampling priors, stopped once k starts in a row have not lowered the best cost "
        "(`scripts/benchmarks/global_peer.py`); k is chosen on the global-optimum net as the smallest that finds "
        "the optimum as often as casest (at most 32 starts per problem).")
    say()
    global_peer.report(16 if quick else 32, say=say)


def bench_streamed_part(quick: bool) -> None:
    """The streamed sweep on a dask LocalCluster (scripts/benchmarks/bench_streamed_sweep.py)."""
    say("## Stage 1 streamed: designs larger than memory")
    say()
    if not _distributed_installed():
        return
    import bench_streamed_sweep

    bench_streamed_sweep.bench(500, [100000, 1000000] if quick else [100000, 1000000, 10000000], 50000, say)


def bench_filters_part(quick: bool) -> None:
    """The EKF over a long record against filterpy and JAX (scripts/benchmarks/bench_filters.py)."""
    import bench_filters

    say("## The EKF over a record (compiled pass, filterpy, JAX)")
    say()
    bench_filters.bench(2000 if quick else 10000, 7, say)


def _write_report(path: str, sections: list, whole: bool, command: str) -> None:
    """Write the report to ``path``, keeping its hand-written reading (from :data:`READING` on).

    The whole set of parts replaces every generated section; some parts replace their own
    sections (found by their ``## `` heading) in the page already there, and the header names
    the command that re-measured them."""
    from casest.data import atomic_write_text

    old = open(path, encoding="utf-8").read() if os.path.exists(path) else ""
    kept = "\n" + old[old.index(READING):] if READING in old else ""
    generated = old[:old.index(READING)] if READING in old else old
    if whole or not generated.strip():
        atomic_write_text(path, "\n".join(LINES) + "\n" + kept)
        return
    blocks = _blocks(generated.rstrip("\n").split("\n"))
    for lines in sections:
        heading = next((line for line in lines if line.startswith("## ")), None)
        index = next((k for k, block in enumerate(blocks) if block and block[0] == heading), None)
        if index is None:
            if blocks[-1] and blocks[-1][-1].strip():
                blocks[-1].append("")  # a blank line before the new section's heading
            blocks.append(list(lines))
        else:
            blocks[index] = list(lines)
    header = blocks[0]
    earlier = [c for line in header if line.startswith("Sections re-measured by") for c in line.split("`")[1::2]]
    commands = [c for c in earlier if c != command] + [command]  # every partial run since the whole one
    note = "Sections re-measured by " + ", then ".join(f"`{c}`" for c in commands) + "."
    header = [line for line in header if not line.startswith("Sections re-measured by")]
    while header and not header[-1].strip():  # one blank line before the note, however often it is rewritten
        header.pop()
    blocks[0] = header + ["", note, ""]
    atomic_write_text(path, "\n".join(line for block in blocks for line in block).rstrip("\n") + "\n\n" + kept)


def _blocks(lines: list) -> list:
    """The page's lines split before every ``## `` heading (the first block: the page's header)."""
    blocks = [[]]
    for line in lines:
        if line.startswith("## "):
            blocks.append([])
        blocks[-1].append(line)
    return blocks


PARTS = {"cold": bench_cold, "stage1": bench_stage1, "stage2": bench_stage2, "dynamic": bench_dynamic,
         "flight": bench_flight_parts, "practice": bench_practice_part, "filters": bench_filters_part, "dask": bench_dask_part, "scaling": bench_scaling,
         "illcond": bench_illconditioned_part, "global": bench_global_part, "streamed": bench_streamed_part}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parts", nargs="+", default=list(PARTS), choices=list(PARTS))
    parser.add_argument("--quick", action="store_true", help="skip the largest sizes")
    parser.add_argument("--out", help="also write the report (Markdown) here")
    parser.add_argument("--keep-cache", action="store_true",
                        help="use the user's compile cache (default: an empty one, so builds include compiles)")
    parser.add_argument("--check", action="store_true",
                        help="re-measure every stated claim (scripts/benchmarks/claims.py check); exit 1 if one leaves "
                             "its range")
    parser.add_argument("--runs", type=int, default=7, help="with --check: runs of each measurement")
    parser.add_argument("--beside", type=int, default=0,
                        help="with --check: measure beside this many CPU-bound processes (a busy machine)")
    parser.add_argument("--scaling-one", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--output-error-one", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.check:
        import claims

        return claims.check(None, args.runs, args.beside)
    if args.output_error_one:
        import json

        print(json.dumps(output_error_one(args.output_error_one)))
        return 0
    if args.scaling_one:
        import json

        print(json.dumps(scaling_one(args.scaling_one)))
        return 0
    if not args.keep_cache:
        cold_state()  # every build below compiles as on a fresh machine, unless a part says otherwise
    command = "python3 scripts/benchmarks/bench.py " + " ".join(argv if argv is not None else sys.argv[1:])
    say(f"# casest benchmarks ({time.strftime('%Y-%m-%d')})")
    say()
    say(f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"NumPy {np.__version__}, CasADi {ca.__version__}. Command: `{command.strip()}`")
    say()
    say("Each table is one run, to read beside the others. The figures casest states, as medians with their "
        "range over at least seven fresh-process runs (ratios of CPU times), the date, the load and the command, are on the "
        "[claims page](benchmark-claims.md), and `python3 scripts/benchmarks/bench.py --check` measures them again.")
    say()
    sections = []
    for part in args.parts:
        start = len(LINES)
        PARTS[part](args.quick)
        sections.append(LINES[start:])
    if args.out:
        _write_report(args.out, sections, whole=set(args.parts) == set(PARTS), command=command.strip())
    return 0


if __name__ == "__main__":
    sys.exit(main())
