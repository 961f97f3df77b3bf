"""NumPy's BLAS held to one thread where casest's products are small (casest.backend.linalg):
OpenBLAS's threads spin while they wait, and on a busy machine identical output-error estimates
then took up to 5x the CPU time of their neighbours."""

import pytest

from casest.backend import linalg


def test_the_blas_runs_on_one_thread_inside_and_as_before_outside():
    threadpoolctl = pytest.importorskip("threadpoolctl")
    before = [lib["num_threads"] for lib in threadpoolctl.threadpool_info() if lib["user_api"] == "blas"]
    if not before:
        pytest.skip("NumPy's BLAS is not one threadpoolctl can see")
    with linalg.single_threaded_blas():
        inside = [lib["num_threads"] for lib in threadpoolctl.threadpool_info() if lib["user_api"] == "blas"]
    after = [lib["num_threads"] for lib in threadpoolctl.threadpool_info() if lib["user_api"] == "blas"]
    assert inside == [1] * len(before) and after == before


def test_without_threadpoolctl_nothing_changes(monkeypatch):
    """The ``threads`` extra not installed: the context is a no-op, not an error."""
    monkeypatch.setattr(linalg, "_CONTROLLER", [None])
    with linalg.single_threaded_blas() as value:
        assert value is None
