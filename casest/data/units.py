"""Units of data columns: conversion to the unit the model declares (pint), and the record of
units the model does not declare."""

from __future__ import annotations

import warnings
from typing import Mapping

import numpy as np

from ..errors import DataError


__all__ = ["convert_to_model_units"]


def _convert_units(name: str, values: np.ndarray, unit: str, declared: str, path: str) -> np.ndarray:
    """Values in the header's ``unit`` converted to the model's ``declared`` unit (pint)."""
    try:
        import pint
    except ImportError:
        raise DataError(
            f"{path}: column {name!r} is in [{unit}] but the model declares [{declared}]; install pint "
            f"(pip install 'casest[units]') to convert it, or convert the column to {declared} yourself"
        ) from None
    registry = _unit_registry(pint)
    try:
        return np.asarray(registry.Quantity(values, unit).to(declared).magnitude, dtype=float)
    except (pint.errors.DimensionalityError, pint.errors.UndefinedUnitError, ValueError, TypeError) as err:
        raise DataError(
            f"{path}: column {name!r} is in [{unit}] but the model declares [{declared}], and the one cannot be "
            f"converted to the other ({type(err).__name__}: {err}); fix the header or the model's unit"
        ) from None


def convert_to_model_units(model, arrays: dict, units: Mapping[str, str], path: str) -> dict:
    """Convert, in place, each column of ``arrays`` whose file unit (``units[name]``) differs
    from the unit the model declares; return the columns whose unit the model does not
    declare (name: unit), used as they are. One warning sums up the conversions, and one the
    undeclared units, however many columns they concern."""
    declared = {s.name: s.unit for s in model.signals}
    declared.update(zip(model.output_names, getattr(model, "output_units", ())))
    undeclared, converted = {}, []
    for name, unit in units.items():
        target = declared.get(name, "")
        if unit and target and unit.replace(" ", "") != target.replace(" ", ""):
            arrays[name] = _convert_units(name, arrays[name], unit, target, path)
            converted.append(f"{name!r} converted from [{unit}] to [{target}]")
        elif unit and not target and name in declared:
            undeclared[name] = unit
    if converted:
        warnings.warn(f"{path}: {len(converted)} column(s) converted to the model's units: " + "; ".join(converted),
                      stacklevel=3)
    if undeclared:
        listed = ", ".join(f"{name!r} is in [{unit}]" for name, unit in undeclared.items())
        warnings.warn(f"{path}: {listed}, but the model declares no unit for it, so it is used as it is; declare "
                      "the unit the model expects (Signal(name, unit=...)) and casest converts it", stacklevel=3)
    return undeclared


_REGISTRY: list = []


def _unit_registry(pint):
    if not _REGISTRY:
        _REGISTRY.append(pint.UnitRegistry())
    return _REGISTRY[0]
