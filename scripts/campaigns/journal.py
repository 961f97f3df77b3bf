"""The journal of a Monte-Carlo campaign: one JSON line per finished run, appended in one write, so
that an interrupted campaign resumes where it stopped (the runs already there are skipped)."""

from __future__ import annotations

import json
import os


def load(path: str) -> list:
    """The rows already in the journal (a line cut short by an interruption is skipped)."""
    rows = []
    if os.path.exists(path):
        with open(path, encoding="utf-8") as fh:
            for line in fh:
                try:
                    rows.append(json.loads(line))
                except ValueError:
                    continue
    return rows


def append(path: str, row: dict) -> None:
    """One row as one write to the journal (O_APPEND): a reader sees whole lines or none of the last."""
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, (json.dumps(row) + "\n").encode())
        os.fsync(fd)
    finally:
        os.close(fd)
