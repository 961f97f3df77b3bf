#!/usr/bin/env python3
"""Monte-Carlo comparison of the two-stage estimator with the paper's benchmarks.

    python3 scripts/campaigns/monte_carlo.py MODEL --runs N --workers W --out DIR
            [--scheduler ADDRESS] [--first-seed S] [--reference-starts K]
            [--covariance hessian|gauss-newton] [--dof-correction] [--figures] [--quiet] [--jit]

Each run draws new noise (seed first_seed + run) and estimates with the proposed
estimator, Benchmark 1 (random start, same box; when the model file has
BENCHMARK1_STARTS), Benchmark 2 (Haupt/Kasdin; change_of_variables()), the single-stage
NLP (SINGLE_STAGE_START) and a K-start reference. A model file's stage_data(data) splits
each record into stage-1 and stage-2 data (paper Table 5). DIR receives config.json,
runs.jsonl (one line per finished run: a re-run with the same DIR resumes), summary.json,
runs.csv and summary.md; --figures adds the landscape and prediction PNGs.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from casest.apps.cli import main  # noqa: E402

if __name__ == "__main__":  # the same as `casest mc ...`
    sys.exit(main(["mc"] + sys.argv[1:]))
