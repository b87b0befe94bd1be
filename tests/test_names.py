"""One name per concept: public class names are unique across the library, a stage package
exports no name that is also one of its submodules (``control.certify`` is always the
module), and a reference has one text form, the older spellings included."""

from __future__ import annotations

import ast
import importlib
import pkgutil
from collections import defaultdict
from pathlib import Path

import pytest

from qsls.pipeline.control.costs import COSTS
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.core.references import ReferenceOptions, parse_reference
from tests.test_layers import LAYERS

PIPELINE = Path(__file__).resolve().parents[1] / "pipeline"


def _top_level(kind: type) -> dict[str, list[str]]:
    found: dict[str, list[str]] = defaultdict(list)
    for f in sorted(PIPELINE.rglob("*.py")):
        for node in ast.parse(f.read_text()).body:
            if isinstance(node, kind) and not node.name.startswith("_"):
                found[node.name].append(f.relative_to(PIPELINE).as_posix())
    return found


def test_public_class_names_are_unique():
    classes = _top_level(ast.ClassDef)
    assert {k: v for k, v in classes.items() if len(v) > 1} == {}
    assert len(classes) > 100  # the scan sees the library


def test_one_reference_grammar():
    assert _top_level(ast.FunctionDef)["parse_reference"] == ["core/references.py"]


@pytest.mark.parametrize("name", LAYERS)
def test_no_package_exports_a_name_that_is_also_a_submodule(name):
    package = importlib.import_module(f"qsls.pipeline.{name}")
    submodules = {m.name for m in pkgutil.iter_modules(package.__path__)}
    assert set(getattr(package, "__all__", ())) & submodules == set()
    for exported in getattr(package, "__all__", ()):  # every listed name resolves
        assert getattr(package, exported) is not None


def test_control_certify_is_the_module_however_it_is_reached():
    import qsls.pipeline.control as control
    from qsls.pipeline.control import certify

    assert certify.__name__ == "qsls.pipeline.control.certify"
    assert control.certify is certify and callable(certify.certify)


@pytest.mark.parametrize(
    "spec",
    [
        "circle:radius=1.5,period=6,center=[0.5,-1]",
        "circle:radius=1.5,period=6,center=0.5;-1",  # the fit's older spelling
        "circle: radius = 1.5 , period=6, center = 0.5 -1",
    ],
)
def test_every_spelling_of_the_centre_gives_the_same_reference(spec):
    ref = parse_reference(spec)
    assert ref == ReferenceOptions(kind="circle", radius=1.5, period=6.0, center=(0.5, -1.0))


def test_reference_errors_are_one_line_and_name_the_option():
    with pytest.raises(
        ConfigError,
        match=r"--reference 'square': unknown kind 'square' \(kinds: circle, hover, figure8",
    ):
        parse_reference("square", "--reference")
    with pytest.raises(ConfigError, match="expected key=value, got 'radius'"):
        parse_reference("circle:radius")
    with pytest.raises(ConfigError, match="unknown option 'radus'; did you mean 'radius'"):
        parse_reference("hover:radus=2")
    assert parse_reference("figure8").kind == "figure8"


ARTIFACT_FILES = {
    "flight.parquet": "ingest/flight.py",
    "error_model.yaml": "errormodel/model.py",
    "controller.npz": "control/controller.py",
    "certificate.yaml": "control/certificate.py",
    "sweep.parquet": "control/sweep.py",
    "s_max.parquet": "control/sweep.py",
    "calibration.json": "calibrate/summary.py",
    "assumptions.parquet": "evaluate/verdict.py",
    "findings.json": "fly/items.py",
    "flights.parquet": "fly/tables.py",
    "per_controller.parquet": "fly/tables.py",
    "camera_frame.npz": "sim/simulate.py",
}
"""Each file that passes between stages, and the one module that spells its name."""


def _prose(tree: ast.AST) -> set[int]:
    """The string constants that are docstrings (module, class, function, attribute)."""
    out: set[int] = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        for stmt in body if isinstance(body, list) else []:
            if (
                isinstance(stmt, ast.Expr)
                and isinstance(stmt.value, ast.Constant)
                and isinstance(stmt.value.value, str)
            ):
                out.add(id(stmt.value))
    return out


def test_each_artifact_file_name_is_spelled_in_its_owner_module_only():
    """Issue 36: readers ask the owner (``CERTIFICATE_FILE``, ``Certificate.load``, ...) instead
    of spelling the name again; docstrings may name the file."""
    found = []
    for f in sorted(PIPELINE.rglob("*.py")):
        rel = f.relative_to(PIPELINE).as_posix()
        tree = ast.parse(f.read_text())
        prose = _prose(tree)
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Constant) and isinstance(node.value, str)):
                continue
            if id(node) in prose:
                continue
            found += [
                f"{rel}:{node.lineno}: {name}"
                for name, owner in ARTIFACT_FILES.items()
                if name in node.value and rel != owner
            ]
    assert found == []


FIGURE_FILES = {
    "perception_error.png": "evaluate/figures.py",
    "distance_to_training.png": "evaluate/figures.py",
    "slope_distribution.png": "errormodel/figures.py",
    "error_norm.png": "errormodel/figures.py",
    "worst_pairs.png": "errormodel/figures.py",
    "feasibility.png": "control/sweep.py",
    "s_max_vs_T.png": "control/sweep.py",
    "metadata.yaml": "ingest/sources/base.py",
}
"""Figures a stage writes and the report reads (and the rosbag2 listing ingest reads), and the
one module that spells each name (issue 49)."""

FIGURE_SPELLINGS_PENDING: set[tuple[str, str]] = set()
"""Figure names still spelled outside their owner (issue 49); may only shrink (none left)."""


def _spellings() -> list[tuple[str, int, str]]:
    """Every string constant in the library that is not a docstring: (module, line, text)."""
    out = []
    for f in sorted(PIPELINE.rglob("*.py")):
        tree = ast.parse(f.read_text())
        prose = _prose(tree)
        rel = f.relative_to(PIPELINE).as_posix()
        out += [
            (rel, node.lineno, node.value)
            for node in ast.walk(tree)
            if isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and id(node) not in prose
        ]
    return out


def test_each_figure_name_is_spelled_in_the_module_that_writes_it():
    """Issue 49: readers (the report, the fit's FIGURES) import the writer's constant."""
    found = {
        (rel, name)
        for rel, _, text in _spellings()
        for name, owner in FIGURE_FILES.items()
        if name in text and rel != owner
    }
    assert found - FIGURE_SPELLINGS_PENDING == set()
    owners = {(rel, n) for rel, _, text in _spellings() for n in FIGURE_FILES if text == n}
    assert owners - FIGURE_SPELLINGS_PENDING == {
        (owner, n) for n, owner in FIGURE_FILES.items()
    }  # each owner spells it


def test_no_figure_file_name_is_spelled_in_two_modules():
    """Any literal ``*.png`` name, listed above or not, has one module (patterns excepted)."""
    modules: dict[str, set[str]] = defaultdict(set)
    for rel, _, text in _spellings():
        if text.endswith(".png") and text[:-4].replace("_", "").isalnum():
            modules[text].add(rel)
    pending = {(rel, n) for rel, n in FIGURE_SPELLINGS_PENDING}
    shared = {n: m for n, m in modules.items() if len({r for r in m if (r, n) not in pending}) > 1}
    assert shared == {}
    assert len(modules) >= 7  # the scan sees the figures


COST_NAMES_SPELLED = {
    "control/costs.py",  # the registry, COSTS: the one place where costs have names
    "control/options.py",  # the config's schema (cost: Literal["qr", "imitation"])
}


def test_cost_names_are_spelled_only_by_the_registry_and_the_config_schema():
    """Issue 49: the library passes Cost objects and asks their properties (``imitates``,
    ``needs_norms``); a name is turned into a cost once, where the config enters
    (``cost_of``), and back only for the certificate's record (``name_of``). Control only:
    elsewhere ``"none"`` and ``"ratio"`` are other things' names (an alignment, a column)."""
    found = sorted(
        f"{rel}:{line}: {text!r}"
        for rel, line, text in _spellings()
        if text in COSTS and rel.startswith("control/") and rel not in COST_NAMES_SPELLED
    )
    assert found == []
    assert {"qr", "imitation", "ratio", "min_phi_xy", "none"} <= set(COSTS)  # the scan's names
