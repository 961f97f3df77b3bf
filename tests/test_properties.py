"""Property-based checks (hypothesis) of the numerical kernels."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from casest.two_stage.sweep import batched_least_squares
from casest.two_stage.result import decode_array, encode_array


@settings(max_examples=60, deadline=None)
@given(
    m=st.integers(1, 4),
    k=st.integers(3, 30),
    n=st.integers(1, 3),
    seed=st.integers(0, 2**32 - 1),
    log_scale=st.floats(-6, 6),
)
def test_batched_least_squares_matches_lstsq(m, k, n, seed, log_scale):
    """Against numpy.linalg.lstsq (SVD) on random full-rank problems with badly scaled columns."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((m, k, n)) * (10.0 ** (log_scale * np.linspace(0, 1, n)))
    y = rng.standard_normal((m, k))
    x, ok = batched_least_squares(A, y)
    assert ok.all()
    for i in range(m):
        ref, *_ = np.linalg.lstsq(A[i], y[i], rcond=None)
        np.testing.assert_allclose(A[i] @ x[i], A[i] @ ref, rtol=1e-8, atol=1e-10 * np.linalg.norm(y[i]))


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=0, max_size=12))
def test_array_encoding_round_trips_every_float(values):
    a = np.array(values, dtype=float)
    b = decode_array(encode_array(a))
    np.testing.assert_array_equal(a, b)
