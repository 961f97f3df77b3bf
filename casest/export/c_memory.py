"""The stack an exported C call uses, measured at export by the compiler that will build it.

:func:`stack_use` compiles the export with ``gcc -O2 -fcallgraph-info=su`` (GCC 10 and later:
each function's frame and the calls between them) and follows the call graph from each public
function: the largest sum of frames along a chain of calls is that call's stack use. A function
whose frame is dynamic (a variable-length array, ``alloca``) makes the use unbounded, and is said
so. libm's own frames are not in the graph (a few dozen bytes on common libms).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile

__all__ = ["stack_use", "call_graph_stack"]

_NODE = re.compile(r'node: \{ title: "([^"]+)" label: "([^"\\]+)\\n[^"]*?\\n(\d+) bytes \(([a-z,]+)\)"')
_EXTERNAL = re.compile(r'node: \{ title: "([^"]+)" label: "[^"]*" shape : ellipse')
_EDGE = re.compile(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"')


def call_graph_stack(graph_text: str, entry_points: tuple) -> dict:
    """Each entry point's stack use from the text of a ``-fcallgraph-info=su`` file.

    Parameters
    ----------
    graph_text : str
        The ``.ci`` file's text (VCG).
    entry_points : tuple of str
        Function names.

    Returns
    -------
    dict
        ``{name: bytes}`` (None where a frame on the way is dynamic; entry points not in the
        graph are left out).
    """
    frames, names, dynamic = {}, {}, set()
    for title, label, size, kind in _NODE.findall(graph_text):
        frames[title], names[label] = int(size), title
        if "dynamic" in kind and "bounded" not in kind:
            dynamic.add(title)
    for title in _EXTERNAL.findall(graph_text):
        frames.setdefault(title, 0)
    calls: dict = {}
    for source, target in _EDGE.findall(graph_text):
        calls.setdefault(source, set()).add(target)
    deepest: dict = {}

    def depth(title: str, path: frozenset):
        if title in dynamic:
            return None
        if title not in deepest:
            below = [depth(c, path | {title}) for c in calls.get(title, ()) if c not in path]
            deepest[title] = None if None in below else frames.get(title, 0) + max(below, default=0)
        return deepest[title]
    return {e: depth(names[e], frozenset()) for e in entry_points if e in names}


def stack_use(source: str, header: str, name: str, entry_points: tuple, compiler: str | None = None) -> dict | None:
    """The largest stack use of the export's public calls, measured (module docstring).

    Parameters
    ----------
    source, header : str
        The texts of ``NAME.c`` and ``NAME.h``.
    name : str
        The C prefix.
    entry_points : tuple of str
        The public functions.
    compiler : str, optional
        A GCC (default: ``gcc`` on the PATH).

    Returns
    -------
    dict or None
        ``{"bytes", "function", "compiler", "calls"}``: the largest use, the call that needs it,
        the compiler's version line, and every entry point's use; None where no GCC is found or
        it cannot report the call graph.
    """
    compiler = compiler or shutil.which("gcc")
    if compiler is None:
        return None
    with tempfile.TemporaryDirectory() as folder:
        for file_name, text in ((name + ".c", source), (name + ".h", header)):
            with open(os.path.join(folder, file_name), "w", encoding="utf-8") as fh:
                fh.write(text)
        try:
            run = subprocess.run([compiler, "-std=c99", "-O2", "-fcallgraph-info=su", "-c", name + ".c", "-o",
                                  name + ".o"], cwd=folder, capture_output=True, text=True, timeout=600)
            version = subprocess.run([compiler, "--version"], capture_output=True, text=True,
                                     timeout=60).stdout.splitlines()[0]
        except (OSError, subprocess.SubprocessError):
            return None
        graph = os.path.join(folder, name + ".ci")
        if run.returncode != 0 or not os.path.exists(graph):
            return None
        with open(graph, encoding="utf-8") as fh:
            calls = call_graph_stack(fh.read(), entry_points)
    if not calls or None in calls.values():
        return None
    function = max(calls, key=calls.get)
    return {"bytes": calls[function], "function": function, "compiler": f"{version} -O2", "calls": calls}
