"""Measurement models as the user declares them: parameters and priors, static models, dynamic
models with their discretisation, and model files."""

from ..errors import ModelError, ModelFileError, OptionError
from .dynamic import INPUT_HOLDS, INTEGRATORS, DynamicModel, Segments, State
from .flight_path import flight_path_columns, flight_path_model
from .modelfile import (
    ModelFileHooks,
    bundled_data_dir,
    bundled_model_names,
    bundled_models_dir,
    load_model_file,
    model_file_frame,
    model_file_hooks,
)
from .priors import Gaussian, LogUniform, Parameter, Signal, Uniform
from .stabilisation import artificially_stabilised, stabilised_dataset
from .static import Model
from .tables import TableCoverage, coverage_notes, lookup_table, table_coverage


__all__ = ["Model", "DynamicModel", "lookup_table", "table_coverage", "coverage_notes", "TableCoverage", "State", "Segments", "Parameter", "Signal", "Uniform", "LogUniform", "Gaussian",
           "ModelError", "ModelFileError", "OptionError", "INTEGRATORS", "INPUT_HOLDS", "load_model_file",
           "model_file_hooks", "model_file_frame", "ModelFileHooks", "bundled_model_names", "bundled_models_dir",
           "bundled_data_dir", "flight_path_model", "flight_path_columns", "artificially_stabilised",
           "stabilised_dataset"]
