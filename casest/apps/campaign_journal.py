"""A campaign's journal: the append-only record of its finished runs (``runs.jsonl``), one
fsynced line per run, read back so that a resumed campaign does every run once."""

from __future__ import annotations

import json as _json
import os as _os
import warnings

from ..data.files import atomic_write_text

__all__ = ["Journal"]


class Journal:
    """Append-only record of finished runs (``runs.jsonl``), one fsynced line per run.

    Opening it drops a torn last line (a run killed mid-write), a line that is not a run record
    (edited, or written by something else: a warning names the line and what is wrong; its run is
    done again) and duplicate runs, and rewrites the file atomically if it had to, so that every
    finished run is kept once.
    """

    def __init__(self, path: str):
        self.path = path
        self.records: dict[int, dict] = {}
        if _os.path.exists(path):
            kept_lines, dirty = [], False
            with open(path, encoding="utf-8") as fh:
                lines = fh.readlines()
            for number, line in enumerate(lines, 1):
                rec, problem = _run_record(line)
                if problem is not None:
                    dirty = True
                    if number < len(lines) or line.endswith("\n"):  # a torn last line is a killed run's
                        warnings.warn(f"{path}, line {number}: not a run record ({problem}); dropped, its run is "
                                      "done again", RuntimeWarning, stacklevel=2)
                    continue
                if rec["run"] in self.records:
                    dirty = True
                    continue
                self.records[rec["run"]] = rec
                kept_lines.append(line if line.endswith("\n") else line + "\n")
            if dirty:
                atomic_write_text(path, "".join(kept_lines))

    def append(self, record: dict) -> None:
        if record["run"] in self.records:
            return
        line = _json.dumps(record) + "\n"
        with open(self.path, "a", encoding="utf-8") as fh:
            fh.write(line)
            fh.flush()
            _os.fsync(fh.fileno())
        self.records[record["run"]] = record


def _run_record(line: str) -> tuple:
    """``(record, None)`` for a line that is a run record as :func:`run_one` writes it, else
    ``(None, what is wrong)``."""
    try:
        rec = _json.loads(line)
    except ValueError:
        return None, "not JSON"
    if not isinstance(rec, dict) or isinstance(rec.get("run"), bool) or not isinstance(rec.get("run"), int) \
            or rec["run"] < 0:
        return None, "no run number"
    methods = rec.get("methods")
    if not isinstance(methods, dict) or not methods:
        return None, "no methods"
    for name, method in methods.items():
        if not isinstance(method, dict):
            return None, f"method {name!r} is not a record"
        for key in ("theta", "std"):
            values = method.get(key)
            if not isinstance(values, list) or not all(v is None or (isinstance(v, (int, float))
                                                                     and not isinstance(v, bool)) for v in values):
                return None, f"{name}.{key} is not a list of numbers"
        if not isinstance(method.get("success"), bool):
            return None, f"{name}.success is not true or false"
    return rec, None
