#!/usr/bin/env python3
"""NIST StRD nonlinear-regression problems under one protocol, casest against SciPy.

    python3 scripts/campaigns/nist_suite.py [FILES...]     (default: ../shared/data/nist_strd/*.dat,
                                                  else the copies in data/nist_strd/)

Protocol: the only prior knowledge is one of the file's two starts, used as the nominal
value, and a box sign(s) [|s|/1000, 1000 |s|] on every parameter the separator finds
nonlinear (linear parameters get none). Every problem runs from start 1 and from start 2
(``--starts 1`` for one). Per problem and start: the fewest correct significant digits
over the parameters (LRE against the certified values), the RSS ratio to the certified
RSS, the correct digits of the standard deviations (Gauss-Newton with the dof correction,
NIST's convention) and the time; beside them scipy.optimize.least_squares (trf) from the
same start with the same bounds, with finite-difference and with analytic (CasADi)
Jacobians.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from casest.apps.cli import main  # noqa: E402

if __name__ == "__main__":  # the same as `casest nist ...`
    sys.exit(main(["nist"] + sys.argv[1:]))
