"""Recursive estimators: the parameters updated sample by sample on one symbolic model."""

from .filter_error import RecursiveFilterErrorML


__all__ = ["RecursiveFilterErrorML"]
