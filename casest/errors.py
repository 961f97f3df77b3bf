"""casest's exceptions: one root, :class:`CasestError`, and one class per kind of mistake.

Every exception casest raises for something the user can fix (a model, a data file, an
option, a result file, a campaign folder) is a :class:`CasestError`; the command line
reports those as user errors (exit status 2) and everything else as casest's own defect.
Each class also derives from ``ValueError`` (``ModelFileError`` from ``FileNotFoundError``
too), so code written against the built-in types keeps working.
"""

from __future__ import annotations


__all__ = [
    "CasestError",
    "OptionError",
    "ModelError",
    "ModelFileError",
    "SeparationError",
    "IdentifiabilityError",
    "DataError",
    "FormulaError",
    "OutputPathError",
    "ResultFileError",
    "CampaignError",
    "MissingExtraError",
]


class CasestError(Exception):
    """The root of every exception casest raises for a mistake the user can fix.

    The message names the problem and the fix: ``except casest.CasestError`` catches every
    such mistake, and nothing that is a defect of casest itself.
    """


class OptionError(CasestError, ValueError):
    """An option that is unknown, out of range or inconsistent with the model or data."""


class ModelError(CasestError, ValueError):
    """A model declaration that cannot be estimated (the message names the symbol)."""


class ModelFileError(ModelError, FileNotFoundError):
    """A model file that cannot be found or loaded, or that raised while it ran (the
    message names the file and the line)."""


class SeparationError(ModelError):
    """The separator cannot split the parameters as asked (a pinned parameter that is not linear)."""


class IdentifiabilityError(ModelError):
    """The data cannot determine some parameters (the message names the combination)."""


class DataError(CasestError, ValueError):
    """A data set or data file that does not fit the model (the message names the column and rows)."""


class FormulaError(CasestError, ValueError):
    """A NIST StRD file, or its model formula, that casest cannot read."""


class ResultFileError(CasestError, ValueError):
    """A saved result that cannot be read back (not a casest file, another version, damaged)."""


class OutputPathError(CasestError, ValueError, OSError):
    """An output path that names something other than a regular file (a device, a FIFO, a folder)."""


class CampaignError(CasestError, ValueError):
    """A Monte-Carlo campaign folder that cannot be used as asked (another configuration, locked)."""


class MissingExtraError(CasestError, ImportError):
    """An optional library a feature needs is not installed (the message names the pip extra)."""

