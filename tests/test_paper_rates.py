"""The paper's Table 1 and Table 3 rates on a reduced Monte-Carlo campaign (120 runs, seeds 0-119).

Expected values: the paper's Tables 1 and 3 (the proposed estimator reaches the truth in 100 %
of its runs; Benchmark 2 in 97.2 % of scalar example 1's) and casest's own 1000-run campaign of
``docs/validation/paper-examples.md`` (``python3 scripts/campaigns/monte_carlo.py scalarK --runs
1000``): there, under the paper's criterion ``||xi_hat - xi_true|| < 0.1``, the proposed estimator
is correct in 94.5 % (scalar 1) and 88.9 % (scalar 2) of the runs, which is the exact ML
optimum's own rate at this noise level, and at the global ML minimum in 100 %; Benchmark 2 is
correct in 92.6 % and at the global minimum in 98.1 %; Benchmark 1 (scalar 2) at the global
minimum in 99.2 %. Each rate is asserted within three binomial standard errors of 120 runs,
``3 sqrt(p (1 - p) / 120)``; a rate of 100 % is asserted in every run (if the true rate were
97 % or less, 120 of 120 would happen with probability below 3 %).
"""

import os

import numpy as np
import pytest

from casest.apps.campaign_summary import summarize
from casest.apps.montecarlo import CampaignConfig, run_one

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RUNS = 120

pytestmark = pytest.mark.slow


def _summary(name: str) -> dict:
    config = CampaignConfig(model=os.path.join(ROOT, "models", f"{name}.py"))
    records = [run_one(config, run) for run in range(RUNS)]
    return summarize(config, records)["methods"]


def _within(pct: float, expected_pct: float) -> bool:
    p = expected_pct / 100
    return abs(pct / 100 - p) <= 3 * np.sqrt(p * (1 - p) / RUNS) + 1e-12


def test_scalar_example_1_rates():
    methods = _summary("scalar1")
    assert methods["proposed"]["global_minimum_pct"] == 100.0  # paper Table 1: 100 %
    assert _within(methods["proposed"]["correct_pct"], 94.5)
    assert methods["benchmark1"]["global_minimum_pct"] == 100.0
    assert _within(methods["benchmark2"]["correct_pct"], 92.6)
    assert _within(methods["benchmark2"]["correct_pct"], 97.2)  # the paper's Table 1 rate, within the same error
    assert _within(methods["benchmark2"]["global_minimum_pct"], 98.1)


def test_scalar_example_2_rates():
    methods = _summary("scalar2")
    assert methods["proposed"]["global_minimum_pct"] == 100.0  # paper Table 3: 100 %
    assert _within(methods["proposed"]["correct_pct"], 88.9)
    assert _within(methods["benchmark1"]["global_minimum_pct"], 99.2)
