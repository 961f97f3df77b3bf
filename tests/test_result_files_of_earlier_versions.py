"""Result files written by earlier versions of casest load, and say what they said then.

Truth: the files under ``tests/data/result_files/<commit>/`` and their text reports, written at that
commit (``tests/data/result_files/write_result_files.py``: 8f8ea55 could save the two-stage,
output-error and filter-error estimates; 1500515 every kind). Loaded today, each gives the same
values, std and conclusion, and the same report but for what today's report shows differently by
design: the residual checks as one Holm family (their statistics and p-values are the same), the
std-choice line naming the independence tests, the count of tests the innovations pass (now
every test of their family, then the whiteness tests alone: the same tests for these files), a
missing std as ``n/a`` where it read ``nan`` or was left out, the fit statistics that today's reports
add (CPU time, a frequency-domain fit's spectra), the process noise as F beside q, and a
filter-error estimate's correlations.
"""

import json
import os
import re

import numpy as np
import pytest

import casest
from casest.equation_error import Regression, Stepwise

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "result_files")
CLASSES = {"two_stage": casest.Estimate, "output_error": casest.Estimate, "filter_error": casest.FilterErrorEstimate,
           "frequency": casest.FrequencyEstimate, "regression": Regression, "stepwise": Stepwise}
FILES = [(commit, kind) for commit in ("8f8ea55", "1500515") for kind in CLASSES
         if os.path.exists(os.path.join(HERE, commit, kind + ".json"))]
#: report sections whose presentation changed by design, and what of then must be in today's section:
#: the residual checks' statistics and p-values; each process-noise intensity with its std (today
#: beside F)
RESTYLED = {"[[Residual checks]]": lambda text: re.findall(r"Q = \S+ on \d+ lags, p = \S+", text),
            "[[Process noise]]": lambda text: [f"{name}: " for name in re.findall(r"q\[(\w+)\] = ", text)]
            + [f"q = {value}" for value in re.findall(r"q\[\w+\] = (\S+(?: \+/- \S+| \(given\)))", text)]}
#: sections today's reports add by design: a filter-error estimate's correlations of every estimated variable
ADDED = ("[[Correlations]]",)
#: sections whose lines of then are all in today's, which lists more statistics (s, PSE; CPU time)
EXTENDED = ("[[Fit Statistics]]",)
#: the same content written as today's report writes it: (then, now)
NOTATION = [(re.compile(r"\+/- nan\b"), "+/- n/a"),
            (re.compile(r"^(    \w+ = \S+) \(held: "), r"\1 +/- n/a (held: "),
            (re.compile(r"^\[\[Parameters\]\] \(value \+/- one standard deviation\)$"),
             "[[Parameters]] (value +/- one standard deviation, white-noise std)"),
            (re.compile(r"the residuals pass the whiteness tests: "),
             "the residuals pass the whiteness tests and the tests of independence: "),
            (re.compile(r"the innovations pass (\d+) whiteness test\(s\)"), r"the innovations pass \1 test(s)"),
            (re.compile(r"^(    seconds            = \S+)$"), r"\1 s wall, CPU not recorded")]


def _sections(report: str) -> dict:
    sections, name = {}, None
    for line in report.splitlines():
        if line.startswith("[["):
            name = line.split("]]")[0] + "]]"
        sections.setdefault(name, []).append(line)
    return sections


def _saved_theta(saved: dict) -> np.ndarray:
    """The estimates as the file holds them: version 1's two layouts (an Estimate's untagged arrays, the
    other results' tagged ones; stepwise's within its final fit)."""
    if "fit" in saved:
        saved = saved["fit"]["result"]
    theta = saved["theta"]["array"] if "array" in saved["theta"] else saved["theta"]
    return np.asarray([float(v) for v in theta["values"]])


def _then_as_now(line: str) -> str:
    for pattern, now in NOTATION:
        line = pattern.sub(now, line)
    return line


def test_files_of_both_commits_are_here():
    assert len(FILES) == 9


@pytest.mark.parametrize("commit, kind", FILES)
def test_an_earlier_file_loads_with_its_numbers_and_report(commit, kind):
    path = os.path.join(HERE, commit, kind + ".json")
    result = CLASSES[kind].from_json(path)
    then = open(os.path.join(HERE, commit, kind + ".report.txt"), encoding="utf-8").read().rstrip("\n")
    now = result.report()
    old, new = _sections(then), _sections(now)
    assert list(old) == [name for name in new if name not in ADDED or name in old]
    for name in old:
        if name in RESTYLED:  # what then said is in today's section
            facts = RESTYLED[name]("\n".join(_then_as_now(line) for line in old[name]))
            assert facts and all(fact in "\n".join(new[name]) for fact in facts), (name, facts)
        elif name in EXTENDED:
            assert all(_then_as_now(line) in new[name] for line in old[name]), name
        else:
            assert [_then_as_now(line) for line in old[name]] == new[name], name
    np.testing.assert_array_equal(np.asarray(result.theta, dtype=float), _saved_theta(json.load(open(path))))
