"""``qsls report RUN_DIR``: one self-contained HTML page and a Markdown twin.

The report reads only the run folder (stage folders, their manifests, ``run.json``), so the
same run folder gives byte-identical output: figures are rendered with fixed metadata, the
only times shown are those the run recorded, and sections come in a fixed order.

``reports/<name>/index.html`` embeds every figure as a base64 PNG (no network, no external
file); ``report.md`` links the same PNG files written beside it.
"""

from __future__ import annotations

import base64
import html
import json
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from qsls.pipeline.artifacts import (
    MANIFEST,
    check_output,
    clean_stale,
    dump_yaml,
    publish,
    read_manifest,
    to_plain,
)
from qsls.pipeline.errors import InputError
from qsls.pipeline.progress import NULL_PROGRESS, Progress

RUN_FILE = "run.json"

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2rem auto;max-width:1100px;
color:#1b1b1b;line-height:1.45;padding:0 1rem}
h1{border-bottom:2px solid #333}h2{margin-top:2.2rem;border-bottom:1px solid #bbb}
table{border-collapse:collapse;margin:.6rem 0;font-size:.88rem}
td,th{border:1px solid #ccc;padding:.2rem .5rem;text-align:right}th{background:#f0f0f0}
td:first-child,th:first-child{text-align:left}
figure{margin:1rem 0}figure img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.85rem;color:#555}
pre{background:#f6f6f6;padding:.7rem;overflow-x:auto;font-size:.8rem}
.ok{color:#16651a;font-weight:600}.bad{color:#a01010;font-weight:600}
"""


# --------------------------------------------------------------------------- document model
@dataclass
class Section:
    title: str
    blocks: list[tuple[str, Any]] = field(default_factory=list)

    def text(self, s: str) -> None:
        self.blocks.append(("text", s))

    def table(
        self, columns: Sequence[str], rows: Sequence[Sequence[Any]], caption: str = ""
    ) -> None:
        self.blocks.append(("table", (list(columns), [list(r) for r in rows], caption)))

    def kv(self, mapping: dict[str, Any], caption: str = "") -> None:
        self.table(["item", "value"], [[k, v] for k, v in mapping.items()], caption)

    def figure(self, name: str, png: bytes, caption: str) -> None:
        self.blocks.append(("figure", (name, png, caption)))

    def code(self, s: str) -> None:
        self.blocks.append(("code", s))


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


def _fmt(v: Any) -> str:
    v = to_plain(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


# --------------------------------------------------------------------------- rendering
def render_html(title: str, sections: Sequence[Section]) -> str:
    out = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        "<nav><ol>"
        + "".join(
            f'<li><a href="#s{i}">{html.escape(s.title)}</a></li>' for i, s in enumerate(sections)
        )
        + "</ol></nav>",
    ]
    for i, s in enumerate(sections):
        out.append(f'<section id="s{i}"><h2>{html.escape(s.title)}</h2>')
        for kind, payload in s.blocks:
            if kind == "text":
                out.append(f"<p>{html.escape(payload)}</p>")
            elif kind == "code":
                out.append(f"<pre>{html.escape(payload)}</pre>")
            elif kind == "table":
                cols, rows, caption = payload
                cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
                head = "".join(f"<th>{html.escape(str(c))}</th>" for c in cols)
                body = "".join(
                    "<tr>" + "".join(f"<td>{html.escape(_fmt(v))}</td>" for v in r) + "</tr>"
                    for r in rows
                )
                out.append(
                    f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
                )
            elif kind == "figure":
                name, png, caption = payload
                b64 = base64.b64encode(png).decode()
                out.append(
                    f'<figure><img alt="{html.escape(name)}" src="data:image/png;base64,{b64}">'
                    f"<figcaption>{html.escape(caption)}</figcaption></figure>"
                )
        out.append("</section>")
    out.append("</body></html>\n")
    return "\n".join(out)


def render_markdown(title: str, sections: Sequence[Section]) -> tuple[str, dict[str, bytes]]:
    lines = [f"# {title}", ""]
    files: dict[str, bytes] = {}
    for s in sections:
        lines += [f"## {s.title}", ""]
        for kind, payload in s.blocks:
            if kind == "text":
                lines += [payload, ""]
            elif kind == "code":
                lines += ["```", payload.rstrip("\n"), "```", ""]
            elif kind == "table":
                cols, rows, caption = payload
                if caption:
                    lines += [f"*{caption}*", ""]
                lines.append("| " + " | ".join(str(c) for c in cols) + " |")
                lines.append("|" + "---|" * len(cols))
                lines += [
                    "| " + " | ".join(_fmt(v).replace("|", "\\|") for v in r) + " |" for r in rows
                ]
                lines.append("")
            elif kind == "figure":
                name, png, caption = payload
                files[name] = png
                lines += [f"![{caption}]({name})", "", f"*{caption}*", ""]
    return "\n".join(lines) + "\n", files


# --------------------------------------------------------------------------- sections
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


def _pngs(folder: Path) -> list[Path]:
    return sorted(
        p
        for p in folder.rglob("*.png")
        if not any(q.startswith(".") for q in p.relative_to(folder).parts)
    )


def _add_figures(sec: Section, run_dir: Path, folder: Path, counter: list[int]) -> None:
    for p in _pngs(folder):
        rel = p.relative_to(run_dir).as_posix()
        counter[0] += 1
        name = f"fig{counter[0]:02d}_" + rel.replace("/", "_")
        sec.figure(name, p.read_bytes(), rel)


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
        _add_figures(sec, run_dir, folder, counter)
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
    from qsls.pipeline import report_sections as rs

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
