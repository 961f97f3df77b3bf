"""Data sets: the measured signals and outputs of a model, read from arrays or CSV files."""

from ..errors import DataError
from .dataset import Dataset, atomic_write_text
from .matfile import read_mat_paths
from .smoothing import fourier_smooth, noise_floor_cutoff, savitzky_golay, zero_phase_lowpass


__all__ = ["Dataset", "DataError", "atomic_write_text", "read_mat_paths", "savitzky_golay", "fourier_smooth", "zero_phase_lowpass",
           "noise_floor_cutoff"]
