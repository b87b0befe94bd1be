"""The stage packages form layers: each imports only the ones below it (imports inside functions
count; ``if TYPE_CHECKING:`` imports do not), so the package import graph has no cycle. Within
and across packages, no two modules import each other, through any chain: imports inside
functions and ``if TYPE_CHECKING:`` imports count too (issue 49), and a ``TYPE_CHECKING``
import names the module that defines what it imports."""

from __future__ import annotations

import ast
from pathlib import Path

PIPELINE = Path(__file__).resolve().parents[1] / "pipeline"
LAYERS = (
    "core",
    "ingest",
    "errormodel",
    "premise",
    "control",
    "export",
    "sim",
    "evaluate",
    "calibrate",
    "fly",
    "report",
    "run",
)
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
    assert "sim/controllers.py" in graph["sim"]["export"]
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


# --------------------------------------------------------------------------- modules
def module_of(f: Path, root: Path = PIPELINE) -> str:
    """The dotted name of a file under ``root`` (``pipeline/`` or ``cli/``; a package's
    ``__init__.py``: the package)."""
    parts = list(f.relative_to(root).with_suffix("").parts)
    return ".".join(["qsls", root.name, *(parts[:-1] if parts[-1] == "__init__" else parts)])


def imported_modules(source: str, here: str, is_package: bool, known: set[str]) -> set[str]:
    """The modules of ``known`` that ``source`` (module ``here``) imports by any statement:
    at the top, inside functions, under ``if TYPE_CHECKING:``. ``from P import n`` imports the
    module ``P.n`` when there is one, else ``P``."""
    package = here if is_package else here.rpartition(".")[0]

    def nearest(name: str) -> str:
        while name and name not in known:
            name = name.rpartition(".")[0]
        return name

    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found |= {nearest(a.name) for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join([*base, module] if module else base)
            for a in node.names:
                full = f"{module}.{a.name}"
                found.add(full if full in known else nearest(module))
    return found - {here, "", "qsls.pipeline"}


def module_graph(sources: dict[str, tuple[str, bool]]) -> dict[str, set[str]]:
    """``{module: modules it imports}`` from ``{module: (source, is_package)}``."""
    known = set(sources)
    return {m: imported_modules(src, m, pkg, known) for m, (src, pkg) in sources.items()}


def pipeline_sources(root: Path = PIPELINE) -> dict[str, tuple[str, bool]]:
    return {
        module_of(f, root): (f.read_text(), f.name == "__init__.py")
        for f in sorted(root.rglob("*.py"))
    }


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every group of modules that import each other through some chain (the strongly
    connected components of more than one module), each sorted, as ``a -> b`` edges."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                members = set(group)
                out.append(sorted(f"{a} -> {b}" for a in members for b in graph[a] if b in members))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def test_the_module_walker_sees_every_import():
    p = "qsls.pipeline.x"
    sources = {
        p: ("", True),
        f"{p}.a": (
            "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import B\n",
            False,
        ),
        f"{p}.b": ("def f():\n    from qsls.pipeline.x import c  # deferred: test\n", False),
        f"{p}.c": ("import qsls.pipeline.x.a\nfrom qsls.pipeline.x import lazy_name\n", False),
        f"{p}.d": ("from . import a\n", False),
    }
    graph = module_graph(sources)
    assert graph[f"{p}.c"] == {f"{p}.a", p} and graph[f"{p}.d"] == {f"{p}.a"}
    assert circles(graph) == [[f"{p}.a -> {p}.b", f"{p}.b -> {p}.c", f"{p}.c -> {p}.a"]]
    assert circles({**graph, f"{p}.a": set()}) == []


def test_no_module_imports_itself_through_a_chain():
    """No import circle between modules of pipeline/, not even through ``TYPE_CHECKING`` or an
    import inside a function: a module depends on what it imports, never the other way too."""
    graph = module_graph(pipeline_sources())
    assert len(graph) > 150 and "qsls.pipeline.control.costs" in graph["qsls.pipeline.control.sls"]
    assert "qsls.pipeline.control.sls" not in graph["qsls.pipeline.control.costs"]
    assert circles(graph) == []


def test_no_cli_module_imports_itself_through_a_chain():
    """The same for the CLI's modules (their imports of pipeline/ point down, out of it)."""
    graph = module_graph(pipeline_sources(PIPELINE.parent / "cli"))
    assert len(graph) > 15 and "qsls.cli.common" in graph["qsls.cli.synth"]
    assert circles(graph) == []


def type_checking_imports(source: str) -> list[tuple[str, str]]:
    """``(module, name)`` of every ``from qsls... import name`` under ``if TYPE_CHECKING:``."""
    out = []
    for block in ast.walk(ast.parse(source)):
        if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test):
            for node in (n for stmt in block.body for n in ast.walk(stmt)):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("qsls."):
                    out += [(node.module or "", a.name) for a in node.names]
    return out


def defined_names(source: str) -> set[str]:
    """The names a module defines at its top level (not the ones it imports)."""
    out = set()
    for node in ast.parse(source).body:
        if isinstance(node, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            out.add(node.name)
        elif isinstance(node, ast.Assign):
            out |= {t.id for t in node.targets if isinstance(t, ast.Name)}
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            out.add(node.target.id)
    return out


def test_a_type_checking_import_names_the_defining_module():
    src = "if TYPE_CHECKING:\n    from qsls.pipeline.a import B, c\n    import numpy\n"
    assert type_checking_imports(src) == [("qsls.pipeline.a", "B"), ("qsls.pipeline.a", "c")]
    assert defined_names("from x import y\nclass B: ...\nc: int = 1\nd = e = 2\n") == {
        "B",
        "c",
        "d",
        "e",
    }
    sources = pipeline_sources()
    wrong = [
        f"{m} imports {name} from {module}"
        for m, (src, _) in sources.items()
        for module, name in type_checking_imports(src)
        if module in sources and name not in defined_names(sources[module][0])
    ]
    assert wrong == []
