"""``qsls report RUN_DIR``: one self-contained HTML page and a Markdown twin.

The report reads only the run folder (stage folders, their manifests, ``run.json``), so the
same run folder gives byte-identical output: figures are rendered with fixed metadata, the
only times shown are those the run recorded, and sections come in a fixed order.

``reports/<name>/index.html`` embeds every figure as a base64 PNG (no network, no external
file); ``report.md`` links the same PNG files written beside it.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from qsls.pipeline.core.artifacts import (
    MANIFEST,
    check_output,
    clean_stale,
    dump_yaml,
    publish,
    read_manifest,
)
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.report.document import Section, add_figures, render_html, render_markdown

RUN_FILE = "run.json"

@dataclass(frozen=True)
class ReportResult:
    out: Path
    n_sections: int
    n_figures: int

    def summary(self) -> dict[str, Any]:
        return {
            "report": str(self.out / "index.html"),
            "markdown": str(self.out / "report.md"),
            "sections": self.n_sections,
            "figures": self.n_figures,
        }


def _stage_dirs(run_dir: Path) -> dict[str, list[Path]]:
    """Stage kind -> folders holding a manifest of that stage, sorted by path."""
    found: dict[str, list[Path]] = {}
    manifests = sorted(run_dir.rglob(MANIFEST))
    folders = {m.parent for m in manifests}
    for m in manifests:
        if any(part.startswith(".") for part in m.relative_to(run_dir).parts):
            continue
        if any(p in folders for p in m.parent.parents):
            continue  # a stage's own sub-stage (e.g. the flights that fly ingests)
        try:
            stage = json.loads(m.read_text()).get("stage", "?")
        except json.JSONDecodeError:
            continue
        found.setdefault(stage, []).append(m.parent)
    return found


def _run_section(run_dir: Path, stages: dict[str, list[Path]]) -> Section:
    sec = Section("What was run")
    run_json = run_dir / RUN_FILE
    info: dict[str, Any] = json.loads(run_json.read_text()) if run_json.is_file() else {}
    sec.kv(
        {
            "run": info.get("name", run_dir.name),
            "qsls version": info.get("qsls_version", "?"),
            "git commit": info.get("git_commit", "unknown"),
            "seed": info.get("seed", "?"),
            "config file": info.get("config_path", "?"),
            "config sha256": info.get("config_sha256", "?"),
        }
    )
    if info.get("config"):
        sec.code(dump_yaml(info["config"]))
    rows = []
    packages: dict[str, str] = {}
    for kind in sorted(stages):
        for folder in stages[kind]:
            m = read_manifest(folder)
            packages = m.get("packages", packages)
            for inp in m.get("inputs", []):
                rows.append(
                    [
                        folder.relative_to(run_dir).as_posix(),
                        Path(inp["path"]).name,
                        inp["sha256"][:16],
                    ]
                )
            if not m.get("inputs"):
                rows.append(
                    [folder.relative_to(run_dir).as_posix(), "(none)", m.get("input_hash", "")[:16]]
                )
    if rows:
        sec.table(["stage folder", "input", "sha256 (16)"], rows, "Inputs of every stage")
    if packages:
        sec.kv(packages, "Package versions")
    return sec


def _manifest_results_section(
    title: str, run_dir: Path, folders: list[Path], counter: list[int]
) -> Section:
    sec = Section(title)
    for folder in folders:
        m = read_manifest(folder)
        results = {
            k: v for k, v in (m.get("results") or {}).items() if not isinstance(v, dict | list)
        }
        if results:
            sec.kv(results, folder.relative_to(run_dir).as_posix())
        add_figures(sec, run_dir, folder, counter)
    return sec


_TITLES = (
    ("simulate", "Simulated flights"),
    ("ingest", "Flights"),
    ("fit", "Error model"),
    ("sweep", "Feasibility sweep"),
    ("synth", "Controllers and certificates"),
    ("evaluate", "Bound check and flown comparison"),
)


def build_sections(run_dir: Path, progress: Progress = NULL_PROGRESS) -> list[Section]:
    stages = _stage_dirs(run_dir)
    if not stages:
        raise InputError(f"{run_dir}: no stage folders found; pass the folder of a 'qsls run'")
    counter = [0]
    sections = [_run_section(run_dir, stages)]
    progress.start("report", total=len(_TITLES))
    from qsls.pipeline.report import sections as rs

    for kind, title in _TITLES:
        folders = stages.get(kind, [])
        if folders:
            builder = getattr(rs, f"section_{kind}", None)
            sec = builder(title, run_dir, folders, counter) if builder else None
            sections.append(sec or _manifest_results_section(title, run_dir, folders, counter))
        progress.advance()
    progress.finish()
    return sections


def report(
    run_dir: Path,
    out: Path | None = None,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
) -> ReportResult:
    """Write ``index.html``, ``report.md`` and the PNGs into ``out`` (default ``reports/<name>``)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise InputError(f"{run_dir}: no such run folder")
    info = json.loads((run_dir / RUN_FILE).read_text()) if (run_dir / RUN_FILE).is_file() else {}
    name = info.get("name", run_dir.name)
    out = Path(out) if out is not None else Path("reports") / name
    check_output(out, force)
    sections = build_sections(run_dir, progress)
    title = f"qsls report: {name}"
    page = render_html(title, sections)
    md, files = render_markdown(title, sections)
    clean_stale(out)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    tmp.mkdir(parents=True, exist_ok=False)
    try:
        (tmp / "index.html").write_text(page)
        (tmp / "report.md").write_text(md)
        for fname, data in files.items():
            (tmp / fname).write_bytes(data)
        publish(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return ReportResult(out=out, n_sections=len(sections), n_figures=len(files))
