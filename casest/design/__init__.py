"""Experiment design: the Fisher information as a CasADi Function, the allocation of
manoeuvres under a time budget, and input design."""

from .experiment import ExperimentDesign, design_experiment
from .inputs import InputDesign, design_inputs
from .information import (CRITERIA, criteria_function, information_function, information_matrix,
                          jacobi_smallest_eigenvalue)


__all__ = ["information_function", "information_matrix", "criteria_function", "jacobi_smallest_eigenvalue", "CRITERIA",
           "ExperimentDesign",
           "design_experiment", "InputDesign", "design_inputs"]
