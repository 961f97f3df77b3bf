"""The MISRA C:2012 check of an export: cppcheck's MISRA addon over the files, each finding
placed in the part of the source that holds it (the header, the code CasADi generated, or casest's
wrapper) and classed mandatory, required or advisory.

casest's wrapper and header hold no mandatory or required violation; the generated kernels'
findings are the deviations of :data:`KERNEL_DEVIATIONS`, each with its reason (the deviation
record, also in the documentation's C-export page). Rule categories are those of MISRA C:2012's
Appendix A with Amendments 1 and 2 (the rules cppcheck 2.x checks); rule texts are MISRA's and are
not reproduced.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from dataclasses import dataclass

from .c_kernel import KERNEL_MARK

__all__ = ["MisraFinding", "misra_findings", "rule_category", "KERNEL_DEVIATIONS", "KERNEL_MARK", "WRAPPER_MARK"]

#: the comment lines where the generated code and casest's wrapper start in an export's source
WRAPPER_MARK = "/* casest's wrapper of the generated step"
#: MISRA C:2012 rules (Appendix A, Amendments 1 and 2) classed mandatory; other rules not in
#: :data:`_ADVISORY` are required
_MANDATORY = frozenset("9.1 12.5 13.6 17.3 17.4 17.6 19.1 21.13 21.17 21.18 21.19 21.20 22.2 22.4 22.5 22.6".split())
_ADVISORY = frozenset("1.2 2.3 2.4 2.5 2.6 2.7 4.2 5.9 8.7 8.9 8.11 8.13 10.5 11.4 11.5 12.1 12.3 12.4 13.3 13.4 "
                      "15.1 15.4 15.5 17.5 17.8 18.4 18.5 19.2 20.1 20.5 20.10 21.12".split())

#: the mandatory and required rules the code CasADi generates deviates from, and why (the
#: deviation record); advisory findings in it are not listed
KERNEL_DEVIATIONS = {
    "8.4": "CasADi's metadata functions (version, argument names and sparsity, work sizes, checkout) have "
           "external linkage and no prior declaration: its interface for loading a Function from a shared "
           "library. The wrapper never calls them; a linker drops them with -ffunction-sections -Wl,--gc-sections.",
    "10.3": "A comparison or if-else of the symbolic expression stored as a number (CasADi represents truth "
            "values as 0 and 1 in its numeric type): the value is exactly 0 or 1.",
    "10.4": "The work-size metadata multiplies an int constant by sizeof (size_t): exact, unused by the wrapper.",
    "11.9": "The metadata functions return 0 for a null name or sparsity pointer: unused by the wrapper.",
    "14.4": "The generated code tests pointers and numbers for non-zero (e.g. `if (sz_arg)` in its work-size "
            "metadata): the wrapper passes every pointer, non-null.",
    "2.2": "The work-size metadata writes `0*sizeof(...)` for an empty work array: no effect, unused by the "
           "wrapper.",
    "16.6": "The metadata's default-argument switch has only a default clause: unused by the wrapper.",
}


@dataclass(frozen=True)
class MisraFinding:
    """One cppcheck MISRA finding.

    Attributes
    ----------
    file : str
        The file's name.
    line : int
    rule : str
        e.g. ``"10.3"``.
    category : {"mandatory", "required", "advisory"}
    part : {"header", "kernel", "wrapper"}
    text : str
        The source line.
    """

    file: str
    line: int
    rule: str
    category: str
    part: str
    text: str


def rule_category(rule: str) -> str:
    """A MISRA C:2012 rule's category.

    Parameters
    ----------
    rule : str
        e.g. ``"15.5"``.

    Returns
    -------
    str
        ``"mandatory"``, ``"required"`` or ``"advisory"``.
    """
    return "mandatory" if rule in _MANDATORY else "advisory" if rule in _ADVISORY else "required"


def misra_findings(folder: str | os.PathLike, name: str, timeout: float = 1200.0) -> list[MisraFinding] | None:
    """cppcheck's MISRA C:2012 findings on an export's ``NAME.c`` and ``NAME.h`` (module docstring).

    Parameters
    ----------
    folder : str or os.PathLike
        The export's folder.
    name : str
        Its C prefix.
    timeout : float
        Seconds cppcheck may take.

    Returns
    -------
    list of MisraFinding or None
        None where cppcheck is not installed.
    """
    if shutil.which("cppcheck") is None:
        return None
    folder = os.fspath(folder)
    run = subprocess.run(["cppcheck", "--std=c99", "--addon=misra", "-q", "--platform=unix64",
                          "--template={file}:{line}:{id}", f"-I{folder}", os.path.join(folder, name + ".c")],
                         capture_output=True, text=True, timeout=timeout)
    lines = {}
    for file_name in (name + ".c", name + ".h"):
        with open(os.path.join(folder, file_name), encoding="utf-8") as fh:
            lines[file_name] = fh.read().splitlines()
    source = lines[name + ".c"]
    kernel = next((i + 1 for i, text in enumerate(source) if text.startswith(KERNEL_MARK)), 0)
    wrapper = next((i + 1 for i, text in enumerate(source) if text.startswith(WRAPPER_MARK)), len(source) + 1)
    findings = []
    for path, line, rule in re.findall(r"^(.+?):(\d+):misra-c2012-(\d+\.\d+)$", run.stderr, flags=re.M):
        file_name, line = os.path.basename(path), int(line)
        if file_name.endswith(".h"):
            part = "header"
        else:  # casest writes the lines before the generated code (its includes) and after it
            part = "kernel" if kernel <= line < wrapper else "wrapper"
        text = lines.get(file_name, [])[line - 1] if 0 < line <= len(lines.get(file_name, [])) else ""
        findings.append(MisraFinding(file_name, line, rule, rule_category(rule), part, text.strip()))
    return findings
