"""Reading CSV text for :meth:`casest.Dataset.from_csv`: the file's text, its delimiter, the
header cells with their units in brackets, and the columns as numbers, each error naming the
file, line and column."""

from __future__ import annotations

import os
import re

import numpy as np

from ..errors import DataError
from .files import readable_file


__all__ = ["parse_header", "read_text", "sniff_delimiter", "csv_header", "csv_columns", "refuse_duplicate_names"]


_HEADER = re.compile(r"^\s*([^\[\]]*?)\s*(?:\[([^\[\]]*)\])?\s*$")



def parse_header(cell: str, path: str = "") -> tuple[str, str]:
    """``'V_N [m/s]'`` -> ``('V_N', 'm/s')``; brackets that do not parse are an error."""
    match = _HEADER.match(cell)
    if not match or not match.group(1):
        raise DataError(
            f"{path + ': ' if path else ''}header cell {cell!r} does not parse: write a name, optionally followed "
            "by one unit in brackets, e.g. 'V_N [m/s]'"
        )
    return match.group(1), (match.group(2) or "").strip()


def read_text(path: str) -> str:
    """A CSV file's text, with clear errors for folders, binary files and other encodings."""
    if not os.path.exists(path):
        raise DataError(f"data file {path!r} does not exist")
    if os.path.isdir(path):
        raise DataError(f"{path!r} is a folder, not a CSV file; give the path of the data file")
    readable_file(path, "data file", DataError)  # a device, FIFO or socket; a file larger than memory takes
    with open(path, "rb") as fh:
        raw = fh.read()
    if b"\x00" in raw[:65536]:
        raise DataError(f"{path!r} is a binary file (it holds NUL bytes), not CSV text; export the data as CSV")
    try:
        return raw.decode("utf-8-sig")  # a UTF-8 byte-order mark is dropped
    except UnicodeDecodeError as err:
        raise DataError(
            f"{path!r} is not UTF-8 text (byte {err.start} cannot be decoded); save it as UTF-8 CSV"
        ) from None


def sniff_delimiter(header: str, path: str) -> str:
    """The header's delimiter among comma, semicolon and tab (the most frequent one)."""
    counts = {d: header.count(d) for d in (",", ";", "\t")}
    best = max(counts, key=counts.get)
    return best if counts[best] else ","


def csv_header(model, header: list, path: str) -> tuple[list, dict]:
    """Column names and units of a CSV header; duplicated names and an unsplit header are refused."""
    parsed = [parse_header(cell, path) for cell in header]
    names = [n for n, _ in parsed]
    refuse_duplicate_names(names, path)
    needed = set(model.signal_names) | set(model.output_names)
    if len(names) == 1 and len(needed) > 1:
        raise DataError(_single_column_cause(header[0], names[0], needed, path))
    return names, dict(parsed)


def _single_column_cause(cell: str, name: str, needed: set, path: str) -> str:
    """Why a header has one field: a comment line first, a file with one of the model's columns
    only, or a delimiter casest did not recognise."""
    if cell.lstrip().startswith("#"):
        return (f"{path}: the first line {cell!r} is a comment; casest reads the column names from the first line: "
                "delete the comment lines above the header")
    if name in needed:
        return (f"{path}: the file holds only the column {name!r}; the model needs {sorted(needed)}, so "
                f"{sorted(needed - {name})} are missing: add them to this file")
    return (f"{path}: the header {cell!r} is a single column but the model needs {sorted(needed)}; the fields are "
            "not separated by a comma, semicolon or tab: pass the delimiter (delimiter=...)")


def refuse_duplicate_names(names: list, path: str) -> None:
    """A DataError naming every duplicated column name and the columns (1-based) that carry it."""
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        where = "; ".join(f"{d!r} in columns {[k + 1 for k, n in enumerate(names) if n == d]}" for d in duplicates)
        raise DataError(f"{path}: duplicated column name(s): {where}; each column needs its own name")


def csv_columns(names: list, rows: list, line_numbers: list, path: str, delimiter: str) -> dict:
    """The CSV rows as float columns (an empty field is NaN); a short row or a non-number names its line."""
    columns: dict[str, list[float]] = {n: [] for n in names}
    for line_no, row in zip(line_numbers, rows):
        if len(row) != len(names):
            raise DataError(f"{path}:{line_no}: {len(row)} fields but the header has {len(names)} "
                            f"(delimiter {delimiter!r})")
        for name, cell in zip(names, row):
            cell = cell.strip()
            try:
                columns[name].append(float(cell) if cell else float("nan"))
            except ValueError:
                hint = " (a decimal comma? write 1.5, not 1,5)" if delimiter != "," and "," in cell else ""
                raise DataError(f"{path}:{line_no}: column {name!r} holds {cell!r}, not a number{hint}") from None
    return {n: np.asarray(v, dtype=float) for n, v in columns.items()}
