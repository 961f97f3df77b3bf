"""The one schema of casest's result files, whichever estimator wrote them.

A result file is a JSON object: ``"format": "casest.<Kind>/<version>"``, then one entry per field
of the result, each written by :func:`encode_field`: JSON's own values where they say it all
(text, whole numbers, finite floats, true/false, null), and a one-key tag where they do not::

    {"array": {"shape": [...], "values": [...]}}      an ndarray, exact ("base64" of its bytes when large),
                                                       with "kind": "int" or "bool" when not float
    {"float": "nan"}                                   a float that is not finite
    {"list": [...]}, {"tuple": [...]}                  a sequence, its type kept
    {"mapping": {"name": ...}}                         a dict of text keys
    {"note": [text, code]}                             a note with its NoteCode
    {"code": value, "type": "StdReason"}               a code of casest.status
    {"record": {...}, "type": "Landscape"}             a registered record (its own to_dict / from_dict)

The content digest of :mod:`casest.estimation.result_files` covers every entry. Files of version 1
still load: the two-stage and filter-error estimates wrote their own layout then (their classes keep
its reader); the others wrote this one with ``{"notes": [[text, code], ...]}`` and ``{"result": ...}``
tags, which :func:`decode_field` reads.
"""

from __future__ import annotations

import dataclasses
import math
from enum import Enum

import numpy as np

from .. import status
from .._casadi.array_json import decode_array, encode_array
from ..errors import ResultFileError
from ..status import Note, NoteCode

__all__ = ["SCHEMA_VERSION", "encode_field", "decode_field", "register_record", "file_format", "format_version"]

#: the version every result type writes; a file of this version or older loads
SCHEMA_VERSION = 2

#: record type name -> the class its saved form loads as (:func:`register_record`)
_RECORDS: dict = {}
#: the codes of casest.status a field may hold, by type name
_CODES = {name: value for name, value in vars(status).items()
          if isinstance(value, type) and issubclass(value, Enum) and value is not Enum}
#: an integer or boolean array's dtype, by its "kind" tag
_ARRAY_KINDS = {"int": np.int64, "bool": bool}


def register_record(cls):
    """Let :func:`decode_field` rebuild ``cls`` (a record with ``to_dict`` / ``from_dict``, or a dataclass)
    from its saved form; usable as a class decorator.

    Parameters
    ----------
    cls : type

    Returns
    -------
    type
        ``cls`` itself.
    """
    _RECORDS[cls.__name__] = cls
    return cls


def file_format(kind: str) -> str:
    """The ``format`` entry a result of ``kind`` writes.

    Parameters
    ----------
    kind : str
        ``"casest.Estimate"``, ``"casest.Regression"``, ...

    Returns
    -------
    str
        ``"<kind>/<SCHEMA_VERSION>"``.
    """
    return f"{kind}/{SCHEMA_VERSION}"


def format_version(found, kind: str, what: str) -> int:
    """The schema version of a file's ``format`` entry, refusing another kind or a newer version.

    Parameters
    ----------
    found : object
        The file's ``format`` entry.
    kind : str
        The kind expected, ``"casest.Estimate"`` for instance.
    what : str
        What the file should hold, for the message.

    Returns
    -------
    int
        From 1 to :data:`SCHEMA_VERSION`.

    Raises
    ------
    ResultFileError
    """
    expected = file_format(kind)
    if isinstance(found, str) and found.startswith(kind + "/") and found.rpartition("/")[2].isdigit():
        version = int(found.rpartition("/")[2])
        if 1 <= version <= SCHEMA_VERSION:
            return version
        if version > SCHEMA_VERSION:
            raise ResultFileError(f"this {what} file was written by a newer casest (format {found!r}; this casest "
                                  f"reads up to {expected!r}): update casest to read it")
    raise ResultFileError(f"not a {what} (format {found!r}, expected {expected!r})")


def encode_field(value):
    """A field's entry in a result file (the module docstring's tags).

    Parameters
    ----------
    value : object
        Text, a number, None, an ndarray, a list, tuple or dict of these, a :class:`~casest.status.Note`,
        a code of :mod:`casest.status`, or a registered record.

    Returns
    -------
    object
        JSON-ready.
    """
    if isinstance(value, Note):
        return {"note": [str(value), value.code.value]}
    if isinstance(value, Enum):
        return {"code": value.value, "type": type(value).__name__}
    if isinstance(value, np.ndarray):
        kind = {"i": "int", "u": "int", "b": "bool"}.get(value.dtype.kind)
        array = {"array": encode_array(value if kind else np.asarray(value, dtype=float))}
        return {**array, "kind": kind} if kind else array
    if type(value).__name__ in _RECORDS and hasattr(value, "to_dict"):
        return {"record": value.to_dict(), "type": type(value).__name__}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {"record": {f.name: encode_field(getattr(value, f.name)) for f in dataclasses.fields(value)},
                "type": type(value).__name__}
    if isinstance(value, (list, tuple)):
        return {type(value).__name__ if type(value) in (list, tuple) else "tuple": [encode_field(v) for v in value]}
    if isinstance(value, dict):
        return {"mapping": {str(k): encode_field(v) for k, v in value.items()}}
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else {"float": str(float(value))}
    if isinstance(value, (np.integer, np.bool_)):
        return value.item()
    return value


def decode_field(value):
    """Inverse of :func:`encode_field` (and the reader of version 1's ``notes`` and ``result`` tags).

    Parameters
    ----------
    value : object
        A field's entry as JSON gave it.

    Returns
    -------
    object

    Raises
    ------
    KeyError
        A record or code type this casest does not know.
    ValueError
        A damaged array.
    """
    if not isinstance(value, dict) or len(value) > 3:
        return value
    if "array" in value:
        return decode_array(value["array"], _ARRAY_KINDS.get(value.get("kind"), float))
    if "float" in value:
        return float(value["float"])
    if "list" in value:
        return [decode_field(v) for v in value["list"]]
    if "tuple" in value:
        return tuple(decode_field(v) for v in value["tuple"])
    if "mapping" in value:
        return {k: decode_field(v) for k, v in value["mapping"].items()}
    if "note" in value:
        return Note(value["note"][0], NoteCode(value["note"][1]))
    if "code" in value and "type" in value:
        return _CODES[value["type"]](value["code"])
    if "notes" in value:  # version 1
        return tuple(Note(text, NoteCode(code)) for text, code in value["notes"])
    if "record" in value or "result" in value:  # "result": version 1's nested result
        return _record(value)
    return value


def _record(value: dict):
    """A registered record from its saved form: through its ``from_dict``, or a dataclass's fields."""
    cls = _RECORDS[value["type"]]
    saved = value.get("record", value.get("result"))
    if hasattr(cls, "from_dict"):
        return cls.from_dict(saved)
    return cls(**{k: decode_field(v) for k, v in saved.items()})
