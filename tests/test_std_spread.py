"""Reported std against the Monte-Carlo spread (statistical check, fixed seeds)."""

import numpy as np

from casest.apps.montecarlo import std_against_spread


def test_scalar2_reported_std_matches_monte_carlo_spread(scalar2):
    """200 seeded runs of paper Eq. 33: mean reported std / sample std in [0.85, 1.15].

    With 200 runs the sample std itself has a relative standard error of about 5 %, so the
    band is three of those either side of 1.
    """
    check = std_against_spread(scalar2, runs=200, first_seed=1000)
    assert check.n_failed == 0
    assert np.all((check.ratio > 0.85) & (check.ratio < 1.15)), check.table()
    # +/-2 std intervals should cover about 95 %; 200 runs give a binomial std of 1.5 %
    assert np.all(check.coverage > 0.95 - 3 * 0.0155), check.table()
