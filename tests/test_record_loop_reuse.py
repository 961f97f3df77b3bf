"""A recursion over a short record runs as the compiled C loop once that loop exists (compiled in
this process for a longer record, or found in the compile cache), and in CasADi's virtual machine
before; the numbers are the same either way.

Truth: the EKF pass of the short-period model file (a random-input record) on the record cut short (below
``jit_min_samples``), compared with itself (1e-10).
"""

import numpy as np
import pytest

import casest
from casest._casadi.numerics import compiler_available
from casest._casadi.record_loop import RecordLoop
from casest.filters import compiled_passes


def test_a_short_record_uses_the_loop_a_long_one_compiled(monkeypatch):
    if not compiler_available():
        pytest.skip("needs a C compiler")
    m = casest.load_model_file("short_period")
    model = m.model()
    R = [m.NOISE_STD[n] ** 2 for n in model.output_names]
    ekf = casest.ExtendedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-6)
    long_record = m.simulate_random(seed=1, duration=120.0)  # 6001 samples at 50 Hz
    short = long_record.subset(np.arange(200))
    assert short.n_samples < casest.SolverSettings().jit_min_samples <= long_record.n_samples
    calls = []
    original = RecordLoop.__call__
    monkeypatch.setattr(RecordLoop, "__call__", lambda self, *a: calls.append(1) or original(self, *a))
    monkeypatch.setattr(compiled_passes, "_LOOPS", {})  # this process has compiled nothing yet
    monkeypatch.setattr(casest._casadi.c_library, "LOADED_LIBRARIES", {})
    monkeypatch.setenv("CASEST_CACHE_DIR", str(pytest.importorskip("tempfile").mkdtemp(prefix="casest_empty_")))
    before = ekf.filter(short)
    assert not calls  # no loop compiled anywhere: the virtual machine
    ekf.filter(long_record)
    assert len(calls) == 1  # the long record compiles the loop
    after = ekf.filter(short)
    assert len(calls) == 2  # ... which the short record now runs
    np.testing.assert_allclose(after.x_filtered, before.x_filtered, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(after.P_filtered, before.P_filtered, rtol=1e-10, atol=1e-18)
