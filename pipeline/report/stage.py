"""``qsls report RUN_DIR``: one self-contained HTML page and a Markdown twin.

The report reads only the run folder (stage folders, their manifests, ``run.json``), so the
same run folder gives byte-identical output: figures are rendered with fixed metadata, the
only times shown are those the run recorded, and sections come in a fixed order.

``RUN/report/index.html`` opens with the summary (one card per controller: status,
premise, guarantee, held-out verdict), then the paper's figures, the evidence section by
section, and the provenance collapsed at the end. It embeds every figure as a base64 PNG (no
network, no external file); ``report.md`` has the same structure and links the same PNG
files written beside it, with the wide tables as CSV files.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from qsls.pipeline import __version__
from qsls.pipeline.core.artifacts import (
    MANIFEST,
    check_output,
    clean_stale,
    dump_json,
    dump_yaml,
    hold_output,
    make_parent,
    make_temporary,
    package_versions,
    publish,
    read_manifest,
    release_output,
    sha256_file,
)
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.report.document import (
    Section,
    figure_of,
    render_html,
    render_markdown,
    stage_pngs,
)
from qsls.pipeline.report.facts import RUN_FILE, Facts, read_facts
from qsls.pipeline.report.summary import summary_section


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


REPORT_DIR = "report"
"""The report's folder inside its run folder."""


def _run_inputs(run_dir: Path, out: Path) -> list[Path]:
    """What the report reads: ``run.json`` and every folder of the run but the report's own
    (so ``RUN/report`` may be written, while an output that is or holds a stage folder is
    refused)."""
    target = out.resolve()
    found = [
        p
        for p in sorted(run_dir.iterdir())
        if not p.name.startswith(".") and (p.is_dir() or p.name == RUN_FILE)
    ]
    return [p for p in found if p.resolve() != target] or [run_dir]


def check_run_folder(run_dir: Path) -> None:
    """Refuse, in one line, a folder that is not a run: missing, a stage's own folder, or a
    folder with neither ``run.json`` nor a stage folder where ``qsls run`` puts them
    (``RUN/fit``, ``RUN/ingest/NAME``, ...)."""
    if not run_dir.is_dir():
        raise InputError(f"{run_dir}: no such run folder")
    if (run_dir / MANIFEST).is_file():
        try:
            stage = json.loads((run_dir / MANIFEST).read_text()).get("stage", "?")
        except json.JSONDecodeError:
            stage = "?"
        raise InputError(
            f"{run_dir}: a '{stage}' stage folder, not a run; pass the run folder that holds "
            "it (written by 'qsls run', e.g. runs/quickstart)"
        )
    if (run_dir / RUN_FILE).is_file():
        return
    if any((run_dir / kind).is_dir() for kind in (*_KNOWN, "fly")):
        return
    raise InputError(
        f"{run_dir}: not a run folder (no {RUN_FILE} and no stage folders such as fit/ or "
        "ingest/NAME/); pass the folder a 'qsls run' wrote, e.g. runs/quickstart"
    )


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
        if stage == "report":  # a report (its own, or another) is no evidence of the run
            continue
        found.setdefault(stage, []).append(m.parent)
    return found


def _provenance_section(f: Facts) -> Section:
    """Config, input hashes, package versions and git commit: the appendix, collapsed."""
    sec = Section("Provenance", id="provenance", collapsed=True)
    info = f.info
    sec.kv(
        {
            "run": f.name,
            "qsls version": info.get("qsls_version", "?"),
            "git commit": info.get("git_commit", "unknown"),
            "seed": info.get("seed", "?"),
            "config file": info.get("config_path", "?"),
            "config sha256": info.get("config_sha256", "?"),
        },
        "The run",
    )
    if info.get("config"):
        sec.heading("Config")
        sec.code(dump_yaml(info["config"]))
    rows = []
    packages: dict[str, str] = {}
    for kind in sorted(f.stages):
        for folder in f.stages[kind]:
            m = read_manifest(folder)
            packages = m.get("packages", packages)
            for inp in m.get("inputs", []):
                rows.append([f.rel(folder), Path(inp["path"]).name, inp["sha256"][:16]])
            if not m.get("inputs"):
                rows.append([f.rel(folder), "(none)", m.get("input_hash", "")[:16]])
    if rows:
        sec.table(
            ["stage folder", "input", "sha256 (first 16)"],
            rows,
            "Inputs of every stage",
            text_cols=[1, 2],
        )
    if packages:
        sec.kv(packages, "Package versions")
    return sec


def _other_section(f: Facts, kind: str, counter: list[int]) -> Section:
    """A stage the report has no section for: its scalar results and its figures."""
    sec = Section(f"Stage: {kind}", id=f"stage-{kind}")
    for folder in f.stages[kind]:
        res = read_manifest(folder).get("results") or {}
        scalars = {k: v for k, v in res.items() if not isinstance(v, dict | list)}
        if scalars:
            sec.kv(scalars, f.rel(folder))
        sec.figures([figure_of(f.run_dir, p, f.rel(p), counter) for p in stage_pngs(folder)])
    return sec


_KNOWN = {"simulate", "ingest", "fit", "sweep", "synth", "calibrate", "evaluate", "fly"}


def build_sections(run_dir: Path, progress: Progress = NULL_PROGRESS) -> list[Section]:
    """Summary first, the paper's figures, the evidence, the appendix last."""
    # deferred: the sections load pandas and scipy; qsls run imports this module to validate
    # a config, which must not (tests/test_config_sections.py)
    from qsls.pipeline.report import calibration as calib
    from qsls.pipeline.report import camera as cam
    from qsls.pipeline.report import certificates as certs
    from qsls.pipeline.report import flights as fl
    from qsls.pipeline.report import monitor as mon
    from qsls.pipeline.report import sections as rs

    stages = _stage_dirs(run_dir)
    if not stages:
        raise InputError(f"{run_dir}: no stage folders found; pass the folder of a 'qsls run'")
    f = read_facts(run_dir, stages)
    counter = [0]
    builders = [
        rs.section_paper_figures,
        certs.section_controllers,
        calib.section_calibration,
        rs.section_heldout,
        rs.section_flown,
        mon.section_monitor,
        rs.section_error_model,
        rs.section_sweep,
        fl.section_flights,
        fl.section_simulated,
        cam.section_camera,
    ]
    if not f.controllers:  # nothing synthesized: the sweep is the answer, it comes first
        builders.remove(rs.section_sweep)
        builders.insert(0, rs.section_sweep)
    progress.start("report", total=len(builders) + 2)
    sections = [summary_section(f)]
    progress.advance()
    for build in builders:
        sec = build(f, counter)
        if sec is not None:
            sections.append(sec)
        progress.advance()
    sections += [_other_section(f, k, counter) for k in sorted(set(stages) - _KNOWN)]
    sections.append(_provenance_section(f))
    progress.advance()
    progress.finish()
    return sections


def _subtitle(info: dict[str, Any], name: str) -> str:
    commit = str(info.get("git_commit") or "unknown")[:10]
    return (
        f"Run {name} from {info.get('config_path', '?')} · qsls {info.get('qsls_version', '?')} "
        f"· commit {commit} · seed {info.get('seed', '?')} · [provenance](#provenance)"
    )


_REPORT_FILES = ("index.html", "report.md", "*.png", "*.csv")


def _run_info(run_dir: Path) -> dict[str, Any]:
    """The run's ``run.json`` (empty when absent); one line when it is not JSON."""
    path = run_dir / RUN_FILE
    if not path.is_file():
        return {}
    try:
        info = json.loads(path.read_bytes())
    except ValueError:
        raise InputError(
            f"{path}: not the JSON file qsls writes; run 'qsls run CONFIG' again to rewrite it"
        ) from None
    return info if isinstance(info, dict) else {}


def _write_manifest(tmp: Path, name: str) -> None:
    """``manifest.json``, as every stage folder has: the stage, the run, each file's sha256
    and the package versions (no wall time: the report's files are byte-identical)."""
    files = {
        f.relative_to(tmp).as_posix(): sha256_file(f)
        for f in sorted(tmp.rglob("*"))
        if f.is_file() and not f.name.startswith(".")
    }
    manifest = {
        "stage": "report",
        "qsls_version": __version__,
        "run": name,
        "files": files,
        "packages": package_versions(),
    }
    (tmp / MANIFEST).write_text(dump_json(manifest))


def report(
    run_dir: Path,
    out: Path | None = None,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
) -> ReportResult:
    """Write ``index.html``, ``report.md`` and the PNGs into ``out`` (default ``RUN/report``:
    the report belongs to its run, so two runs of one config never share one)."""
    run_dir = Path(run_dir)
    check_run_folder(run_dir)
    info = _run_info(run_dir)
    name = info.get("name", run_dir.name)
    out = Path(out) if out is not None else run_dir / REPORT_DIR
    # a report written before reports had a manifest: its own files only
    check_output(out, force, _run_inputs(run_dir, out), known=_REPORT_FILES)
    sections = build_sections(run_dir, progress)
    title = f"qsls report: {name}"
    subtitle = _subtitle(info, name)
    page = render_html(title, subtitle, sections)
    md, files = render_markdown(title, subtitle, sections)
    make_parent(out, "output folder")
    hold_output(out)
    clean_stale(out)
    tmp = make_temporary(out)
    try:
        (tmp / "index.html").write_text(page)
        (tmp / "report.md").write_text(md)
        for fname, data in files.items():
            (tmp / fname).write_bytes(data)
        _write_manifest(tmp, name)
        publish(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        release_output(out)
    return ReportResult(out=out, n_sections=len(sections), n_figures=len(files))
