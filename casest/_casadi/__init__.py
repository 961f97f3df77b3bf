"""CasADi plumbing that knows nothing of models: evaluation, JIT compilation, the compile cache,
the in-process caches."""
