#!/usr/bin/env python3
"""Estimate a model's parameters and print the report.

    python3 scripts/examples/solve.py MODEL [--data CSV] [--stage1-data CSV] [--seed N]
                                   [--mode auto|reduced|full|alternating]
                                   [--covariance hessian|gauss-newton] [--dof-correction]
                                   [--json OUT] [--save-data CSV]

MODEL is a file path or the name of a bundled model in models/ (scalar1, scalar2, ...).
Without --data the model file's simulate(seed) makes a data set with known truth, and
the truth is printed beside the estimate.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from casest.apps.cli import main  # noqa: E402

if __name__ == "__main__":  # the same as `casest solve ...`
    sys.exit(main(["solve"] + sys.argv[1:]))
