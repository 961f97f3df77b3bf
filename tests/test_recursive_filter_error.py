"""Recursive filter-error ML (casest.recursive.RecursiveFilterErrorML, summary Eq. 5.10-5.13 with the
EKF's innovations and their covariance).

Truth: the batch filter-error estimate (casest.filter_error_estimate, the same process noise and
R held) of the same simulated closed-loop oscillator record (tests/test_filters.py: process noise
on the rate, the input feeding back the measured rate; seed 0, 10000 samples): the recursive
estimate, started 20 % off, ends within 0.5 of the batch std, and its own std within 10 % of the
batch std.
"""

import numpy as np
import pytest

import casest
from casest.errors import OptionError
from casest.recursive import RecursiveFilterErrorML
from test_filters import LOOP_NOISE, LOOP_Q, LOOP_TRUTH, loop_model, loop_record


@pytest.mark.slow
def test_the_recursion_reaches_the_batch_filter_error_estimate():
    model = loop_model()
    data = loop_record(model, 0, N=10000)
    batch = casest.filter_error_estimate(model, data, {"v": LOOP_Q}, estimate_process_noise=False, R=LOOP_NOISE**2)
    start = {k: 0.8 * v for k, v in LOOP_TRUTH.items()}
    online = RecursiveFilterErrorML(model, start, {"v": LOOP_Q}, LOOP_NOISE**2, forgetting=0.9, forgetting_rate=0.995)
    history = online.run(data)
    assert history.shape == (10000, 3) and np.allclose(history[-1], online.theta)
    assert np.all(np.abs(online.theta - batch.theta) < 0.5 * batch.std), (online.theta - batch.theta) / batch.std
    assert np.all(np.abs(online.std / batch.std - 1) < 0.1), online.std / batch.std


def test_mistakes_are_named():
    model = loop_model()
    with pytest.raises(OptionError, match="outside the bounds"):
        RecursiveFilterErrorML(model, {"a": -5.0, "k": 4.0, "b": 1.0}, {"v": LOOP_Q}, LOOP_NOISE**2)
    with pytest.raises(OptionError, match="call start"):
        RecursiveFilterErrorML(model, LOOP_TRUTH, {"v": LOOP_Q}, LOOP_NOISE**2).update([0.0, 0.0], [0.0], [0.0], [0.0], 0.02)
    with pytest.raises(OptionError, match="R must be positive semi-definite"):
        RecursiveFilterErrorML(model, LOOP_TRUTH, {"v": LOOP_Q}, [-1.0, 0.1])
