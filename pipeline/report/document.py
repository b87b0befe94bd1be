"""The report as a document: sections of text, tables, key-value lists and figures, rendered
to one self-contained HTML page (figures embedded as base64 PNG) and to Markdown."""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from qsls.pipeline.core.artifacts import to_plain

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
def _pngs(folder: Path) -> list[Path]:
    return sorted(
        p
        for p in folder.rglob("*.png")
        if not any(q.startswith(".") for q in p.relative_to(folder).parts)
    )


def add_figures(sec: Section, run_dir: Path, folder: Path, counter: list[int]) -> None:
    for p in _pngs(folder):
        rel = p.relative_to(run_dir).as_posix()
        counter[0] += 1
        name = f"fig{counter[0]:02d}_" + rel.replace("/", "_")
        sec.figure(name, p.read_bytes(), rel)
