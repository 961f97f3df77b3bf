"""The pendulum case of the filter benchmarks, shared by bench_filters.py and ekf_numba_peer.py:
gravity (m/s^2), the sampling interval (s) and the RK4 substeps per interval."""

G, DT, SUBSTEPS = 9.81, 0.05, 4
