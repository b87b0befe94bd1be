"""The stage packages form layers: each imports only the ones below it (imports inside functions
count; ``if TYPE_CHECKING:`` imports do not), so the package import graph has no cycle."""

from __future__ import annotations

import ast
from pathlib import Path

PIPELINE = Path(__file__).resolve().parents[1] / "pipeline"
LAYERS = ("core", "ingest", "errormodel", "control", "export", "sim", "evaluate", "report", "run")
"""Bottom to top."""


def imported_packages(source: str, here: str) -> set[str]:
    """The stage packages other than its own that ``source`` imports anywhere (``here``: the
    dotted package holding the module, for relative imports); ``TYPE_CHECKING`` blocks skipped."""
    tree = ast.parse(source)
    skip = {
        id(node)
        for block in ast.walk(tree)
        if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test)
        for stmt in block.body
        for node in ast.walk(stmt)
    }
    found: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:
                base = here.split(".")[: len(here.split(".")) - node.level + 1]
                module = ".".join([*base, module] if module else base)
            names = (
                [f"{module}.{a.name}" for a in node.names]
                if module == "qsls.pipeline"
                else [module]
            )
        for name in names:
            parts = name.split(".")
            if parts[:2] == ["qsls", "pipeline"] and len(parts) > 2 and parts[2] in LAYERS:
                found.add(parts[2])
    found.discard(here.split(".")[2])
    return found


def package_graph() -> dict[str, dict[str, list[str]]]:
    """``{package: {imported package: [files that import it]}}`` over ``pipeline/``."""
    graph: dict[str, dict[str, list[str]]] = {}
    for f in sorted(PIPELINE.rglob("*.py")):
        parts = f.relative_to(PIPELINE).parts
        if len(parts) < 2:
            continue
        here = ".".join(["qsls", "pipeline", *parts[:-1]])
        for dep in imported_packages(f.read_text(), here):
            graph.setdefault(parts[0], {}).setdefault(dep, []).append(
                f.relative_to(PIPELINE).as_posix()
            )
    return graph


def cycles(graph: dict[str, dict[str, list[str]]]) -> list[list[str]]:
    """Every elementary cycle through the smallest-named package in it (depth-first)."""
    out = []
    for start in sorted(graph):

        def walk(node: str, path: list[str], start: str = start) -> None:
            for nxt in graph.get(node, {}):
                if nxt == start:
                    out.append([*path, start])
                elif nxt > start and nxt not in path:
                    walk(nxt, [*path, nxt])

        walk(start, [start])
    return out


def test_the_walker_sees_imports_in_functions_and_skips_type_checking():
    src = (
        "from typing import TYPE_CHECKING\n"
        "from qsls.pipeline.core.errors import InputError\n"
        "if TYPE_CHECKING:\n    from qsls.pipeline.report.facts import Facts\n"
        "def f():\n    from qsls.pipeline.export.cbuild import c_runtime\n"
        "    import qsls.pipeline.ingest.flight\n"
        "from qsls.pipeline import evaluate\n"
        "from ..run import runner\n"
        "from . import sls\n"
    )
    assert imported_packages(src, "qsls.pipeline.control") == {
        "core",
        "export",
        "ingest",
        "evaluate",
        "run",
    }
    assert cycles({"a": {"b": []}, "b": {"c": []}, "c": {"a": [], "b": []}}) == [
        ["a", "b", "c", "a"],
        ["b", "c", "b"],
    ]
    nested = "from .. import stage\nfrom ...sim import vio\n"
    assert imported_packages(nested, "qsls.pipeline.ingest.sources") == {"sim"}


def test_every_stage_package_has_a_layer():
    packages = {p.name for p in PIPELINE.iterdir() if (p / "__init__.py").is_file()}
    assert packages == set(LAYERS)


def test_stage_packages_import_only_downward_and_never_in_a_cycle():
    graph = package_graph()
    assert cycles(graph) == []
    upward = [
        f"{pkg} -> {dep} ({', '.join(files)})"
        for pkg, deps in graph.items()
        for dep, files in deps.items()
        if LAYERS.index(dep) > LAYERS.index(pkg)
    ]
    assert upward == []
    # the graph is real: the top layer reaches down to every stage it runs
    assert {"ingest", "errormodel", "control", "sim", "evaluate", "report"} <= set(graph["run"])


def test_the_simulator_imports_the_c_backend_it_flies():
    """export sits below sim (issue 36): the simulator imports the compiled-C runtime where it
    flies it, with no registry a caller has to fill by a side-effect import first."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import qsls.pipeline.sim.controllers as sc\n"
        "import qsls.pipeline.export.cbuild as cb\n"
        "print(sc.c_runtime is cb.c_runtime, hasattr(sc, '_RUNTIMES'))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "False"]
    graph = package_graph()
    assert graph["sim"]["export"] == ["sim/controllers.py"]
    assert "sim" not in graph.get("export", {})
    callers = [
        f.relative_to(PIPELINE.parent).as_posix()
        for d in (PIPELINE, PIPELINE.parent / "cli")
        for f in sorted(d.rglob("*.py"))
        if "registers the 'c' controller runtime" in f.read_text()
    ]
    assert callers == []


def undeferred_imports(source: str) -> list[int]:
    """Lines of the imports of qsls modules inside functions that no ``# deferred: <why>``
    comment explains (on the import's lines, or on the comment and import lines just above
    it: one comment may head a group)."""
    tree = ast.parse(source)
    lines = source.splitlines()
    found = []
    for fn in ast.walk(tree):
        if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.ImportFrom):
                internal = node.level > 0 or (node.module or "").split(".")[0] == "qsls"
            elif isinstance(node, ast.Import):
                internal = any(a.name.split(".")[0] == "qsls" for a in node.names)
            else:
                continue
            if not internal:
                continue
            own = lines[node.lineno - 1 : node.end_lineno]
            above, i = [], node.lineno - 2
            while i >= 0 and lines[i].strip().startswith(("#", "from ", "import ", ")")):
                above.append(lines[i])
                i -= 1
            if not any("# deferred:" in line for line in own + above):
                found.append(node.lineno)
    return sorted(set(found))


def test_the_walker_finds_imports_in_functions_that_no_comment_defers():
    src = (
        "from qsls.pipeline.core import errors\n"
        "def f():\n    from qsls.pipeline.control import sls\n"
        "def g():\n    # deferred: a cycle\n    from qsls.pipeline.control import sls\n"
        "    from qsls.pipeline.control import taps\n"
        "def h():\n    import numpy\n    from . import sibling  # deferred: a cycle\n"
        "    x = 1\n\n    from ..core import units\n"
    )
    assert undeferred_imports(src) == [3, 13]


def test_imports_inside_functions_are_deferred_on_purpose():
    """The import graph is read at the top of each module (issue 36): an import of a qsls
    module inside a function stays there only for a cycle or for a heavy import a light
    entry point must not pay, and a ``# deferred:`` comment says which."""
    found = {
        f.relative_to(PIPELINE).as_posix(): lines
        for f in sorted(PIPELINE.rglob("*.py"))
        if (lines := undeferred_imports(f.read_text()))
    }
    assert found == {}
