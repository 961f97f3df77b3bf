"""Applications built on the estimator: the command line, Monte-Carlo campaigns, plots, the
paper's baselines, the NIST StRD suite and the flight simulators (imported on use)."""
