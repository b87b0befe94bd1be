"""The report as a document: sections of text, cards, tables, figures and collapsed
appendices, rendered to one self-contained HTML page (figures embedded as base64 PNG) and
to Markdown with the same structure (figures and CSV files beside it).

Text may hold links written as ``[label](#section-id)`` or ``[label](file.csv)``; both
renderings keep them. Only ``http``/``https`` and relative targets become links
(:func:`safe_href`): a name that holds ``[x](javascript:...)`` is shown as text. The
Markdown twin escapes ``<``, ``>`` and ``&`` in every text it carries, so no name is raw HTML
there. Tables stay narrow: long texts go to numbered notes under the table,
wide data to a CSV file beside the report (``Table.csv``).
"""

from __future__ import annotations

import base64
import html
import math
import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from qsls.pipeline.core.artifacts import to_plain

_CSS = """
:root{--ink:#1d1d1f;--muted:#5b5b60;--line:#dadadf;--ok:#0b6b47;--warn:#7a4a00;--bad:#a8201a}
*{box-sizing:border-box}
body{margin:0;color:var(--ink);font:15px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif}
main{max-width:1160px;margin:0 auto;padding:0 24px 48px}
header{padding:14px 0 6px;border-bottom:2px solid var(--ink)}
h1{font-size:1.45rem;margin:0}
.sub{color:var(--muted);font-size:.88rem;margin:.15rem 0 0}
nav{display:flex;flex-wrap:wrap;gap:.1rem .9rem;font-size:.85rem;padding:.35rem 0;border-bottom:1px solid var(--line)}
nav a{white-space:nowrap}
a{color:#0b57a4;text-decoration:none}a:hover{text-decoration:underline}
h2{font-size:1.2rem;margin:1.8rem 0 .5rem;padding-bottom:.15rem;border-bottom:1px solid var(--line)}
#summary h2{margin-top:.8rem}
h3{font-size:1rem;margin:1.1rem 0 .3rem}
p{margin:.45rem 0;max-width:75em}
ul.facts{margin:.35rem 0;padding-left:1.2rem}ul.facts li{margin:.12rem 0}
.lead{font-size:1.02rem}
.cards{display:grid;grid-template-columns:repeat(auto-fill,minmax(255px,1fr));gap:10px;margin:.6rem 0}
.card{border:1px solid var(--line);border-left:6px solid var(--c,#888);border-radius:6px;
padding:.5rem .7rem;font-size:.87rem}
.card h3{margin:0 0 .25rem;font-size:.98rem;overflow-wrap:anywhere}
.card dl{display:grid;grid-template-columns:auto 1fr;gap:0 .6rem;margin:.3rem 0}
.card dt{color:var(--muted)}.card dd{margin:0;text-align:right;white-space:nowrap;font-variant-numeric:tabular-nums}
.card p{margin:.25rem 0}.card .links{font-size:.8rem}
.card .promise{font-size:.86rem}
.badge{display:inline-block;padding:0 .4rem;border-radius:3px;font-size:.78rem;font-weight:600}
.ok{color:var(--ok)}.warn{color:var(--warn)}.bad{color:var(--bad)}.muted{color:var(--muted)}
.badge.ok{background:#e1f2e9}.badge.warn{background:#fcefd2}.badge.bad{background:#fbe1df}
.badge.muted{background:#ececef}
.tablewrap{overflow-x:auto;max-width:100%;margin:.5rem 0}
table{border-collapse:collapse;font-size:.86rem;font-variant-numeric:tabular-nums}
p.cap{font-weight:600;margin:.9rem 0 .2rem}
th,td{padding:.22rem .6rem;border-bottom:1px solid var(--line);text-align:right;white-space:nowrap}
th{background:#f3f3f5;font-weight:600;vertical-align:bottom;white-space:normal;min-width:4.5em}
td:first-child,th:first-child{text-align:left}
td.t,th.t{text-align:left}td.w{text-align:left;white-space:normal;min-width:16em;max-width:38em}
td.ww{text-align:left;white-space:normal;min-width:24em;max-width:48em}
ol.notes{font-size:.84rem;color:#333;margin:.2rem 0 .8rem;padding-left:1.6rem;max-width:75em}
.csv{font-size:.84rem}
.figs{display:grid;grid-template-columns:repeat(auto-fit,minmax(490px,1fr));gap:14px;margin:.6rem 0}
.figs figure.wide{grid-column:1/-1}
figure{margin:0}
figure img{display:block;max-width:100%;height:auto;border:1px solid #e6e6ea}
figcaption{font-size:.84rem;color:var(--muted);margin-top:.2rem}
details{border:1px solid var(--line);border-radius:6px;padding:.3rem .8rem;margin:1.8rem 0}
details>summary{cursor:pointer;font-weight:600;font-size:1.1rem;padding:.3rem 0}
pre{background:#f6f6f8;padding:.6rem;font-size:.78rem;white-space:pre-wrap;overflow-wrap:anywhere}
"""

_LINK = re.compile(r"\[([^\]\n]+)\]\(([^)\s]+)\)")
_BOLD = re.compile(r"\*\*([^*\n]+)\*\*")
_WIDE_PX = 620  # a figure wider than this takes the whole row


# --------------------------------------------------------------------------- document model
@dataclass(frozen=True)
class Table:
    columns: list[str]
    rows: list[list[Any]]
    caption: str = ""
    notes: list[str] = field(default_factory=list)
    csv: str = ""  # file beside the report holding the full data
    text_cols: tuple[int, ...] = ()  # columns aligned left (names, short words)
    wrap_cols: tuple[int, ...] = ()  # left-aligned columns whose text may wrap (claims)
    wide_cols: tuple[int, ...] = ()  # wrapping columns of long prose (reasons), wider lines


@dataclass(frozen=True)
class Figure:
    name: str
    png: bytes
    caption: str

    @property
    def width(self) -> int:
        return int(struct.unpack(">I", self.png[16:20])[0]) if self.png[:4] == b"\x89PNG" else 0

    @property
    def height(self) -> int:
        return int(struct.unpack(">I", self.png[20:24])[0]) if self.png[:4] == b"\x89PNG" else 0


@dataclass(frozen=True)
class Card:
    title: str
    colour: str
    badge: str
    kind: str  # ok | warn | bad | muted
    items: list[tuple[str, str]]
    verdict: str
    verdict_kind: str
    links: list[tuple[str, str]] = field(default_factory=list)
    note: str = ""  # a muted line under the numbers (the premise's shares)
    verdict_label: str = "Flown flights"  # whose flights ``verdict`` is about
    more: list[tuple[str, str, str]] = field(default_factory=list)  # (label, text, kind)
    promise: str = ""  # what the certificate promises, first (evaluate/verdict.py:promise)


@dataclass
class Section:
    title: str
    id: str = ""
    collapsed: bool = False
    blocks: list[tuple[str, Any]] = field(default_factory=list)

    def text(self, s: str, lead: bool = False) -> None:
        self.blocks.append(("lead" if lead else "text", s))

    def heading(self, s: str) -> None:
        self.blocks.append(("h3", s))

    def bullets(self, items: Sequence[str]) -> None:
        if items:
            self.blocks.append(("list", list(items)))

    def cards(self, cards: Sequence[Card]) -> None:
        if cards:
            self.blocks.append(("cards", list(cards)))

    def table(
        self,
        columns: Sequence[str],
        rows: Sequence[Sequence[Any]],
        caption: str = "",
        *,
        notes: Sequence[str] = (),
        csv: str = "",
        text_cols: Sequence[int] = (),
        wrap_cols: Sequence[int] = (),
        wide_cols: Sequence[int] = (),
    ) -> None:
        t = Table(
            list(columns),
            [list(r) for r in rows],
            caption,
            list(notes),
            csv,
            tuple(text_cols),
            tuple(wrap_cols),
            tuple(wide_cols),
        )
        self.blocks.append(("table", t))

    def kv(self, mapping: dict[str, Any], caption: str = "") -> None:
        self.table(["item", "value"], [[k, v] for k, v in mapping.items()], caption, text_cols=[1])

    def figure(self, name: str, png: bytes, caption: str) -> None:
        self.figures([Figure(name, png, caption)])

    def figures(self, figs: Sequence[Figure]) -> None:
        if figs:
            self.blocks.append(("figures", list(figs)))

    def code(self, s: str) -> None:
        self.blocks.append(("code", s))

    def attach(self, name: str, data: bytes) -> str:
        """A file written beside the report (a table's full data); returns its name."""
        self.blocks.append(("file", (name, data)))
        return name

    def files(self) -> dict[str, bytes]:
        """The figures this section shows and the files it attaches, by file name."""
        out: dict[str, bytes] = {}
        for kind, payload in self.blocks:
            if kind == "figures":
                out.update({f.name: f.png for f in payload})
            elif kind == "file":
                out[payload[0]] = payload[1]
        return out


def fmt(v: Any, digits: int = 4) -> str:
    """A cell: floats to ``digits`` significant digits, booleans yes/no, missing as '-'."""
    v = to_plain(v)
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        if v == int(v) and abs(v) < 1e6:
            return str(int(v))
        return f"{v:.{digits}g}"
    if isinstance(v, list):
        return "[" + ", ".join(fmt(x, digits) for x in v) + "]"
    return str(v)


# --------------------------------------------------------------------------- links
_SCHEME = re.compile(r"([A-Za-z][A-Za-z0-9+.\-]*):")


def safe_href(target: str) -> str | None:
    """``target`` when it may be a link: ``http``/``https``, or relative (a section
    ``#id``, a file beside the report); None for anything else (``javascript:``,
    ``data:``, ``//host``, control characters or backslashes a browser would strip)."""
    if not target or "\\" in target or any(ord(c) < 0x21 or ord(c) == 0x7F for c in target):
        return None
    m = _SCHEME.match(target)
    if m:
        return target if m.group(1).lower() in ("http", "https") else None
    return None if target.startswith("//") else target


# --------------------------------------------------------------------------- HTML
def _escape(s: str) -> str:
    return _BOLD.sub(r"<strong>\1</strong>", html.escape(s))


def _inline(s: str) -> str:
    """Escape text, then turn ``[label](target)`` into links and ``**x**`` into bold."""
    out, pos = [], 0
    for m in _LINK.finditer(s):
        out.append(_escape(s[pos : m.start()]))
        href = safe_href(m.group(2))
        if href is None:  # shown as written, never a live link
            out.append(_escape(m.group(0)))
        else:
            out.append(f'<a href="{html.escape(href)}">{html.escape(m.group(1))}</a>')
        pos = m.end()
    out.append(_escape(s[pos:]))
    return "".join(out)


def _html_table(t: Table) -> str:
    cap = f'<p class="cap">{_inline(t.caption)}</p>' if t.caption else ""
    cls = (
        {j: ' class="t"' for j in t.text_cols}
        | {j: ' class="w"' for j in t.wrap_cols}
        | {j: ' class="ww"' for j in t.wide_cols}
    )
    head = "".join(
        f"<th{' class=t' if j in cls else ''}>{html.escape(str(c))}</th>"
        for j, c in enumerate(t.columns)
    )
    body = "".join(
        "<tr>"
        + "".join(f"<td{cls.get(j, '')}>{_inline(fmt(v))}</td>" for j, v in enumerate(r))
        + "</tr>"
        for r in t.rows
    )
    out = [
        f'{cap}<div class="tablewrap"><table><thead><tr>{head}</tr></thead>'
        f"<tbody>{body}</tbody></table></div>"
    ]
    if t.notes:
        out.append(
            '<ol class="notes">' + "".join(f"<li>{_inline(n)}</li>" for n in t.notes) + "</ol>"
        )
    if t.csv:
        out.append(f'<p class="csv">Every column: <a href="{html.escape(t.csv)}">{t.csv}</a></p>')
    return "\n".join(out)


def _html_card(c: Card) -> str:
    items = "".join(f"<dt>{html.escape(k)}</dt><dd>{html.escape(v)}</dd>" for k, v in c.items)
    links = " · ".join(
        f'<a href="{html.escape(h)}">{html.escape(t)}</a>'
        if safe_href(h) is not None
        else html.escape(t)
        for t, h in c.links
    )
    return (
        f'<div class="card" style="--c:{html.escape(c.colour)}">'
        f"<h3>{html.escape(c.title)}</h3>"
        f'<span class="badge {c.kind}">{html.escape(c.badge)}</span>'
        + (f'<p class="promise">{html.escape(c.promise)}</p>' if c.promise else "")
        + f"<dl>{items}</dl>"
        + (f'<p class="muted">{_inline(c.note)}</p>' if c.note else "")
        + "".join(
            f'<p class="{kind}"><b>{html.escape(label)}:</b> {_inline(text)}</p>'
            for label, text, kind in [(c.verdict_label, c.verdict, c.verdict_kind), *c.more]
        )
        + (f'<p class="links">{links}</p>' if links else "")
        + "</div>"
    )


def _html_figure(f: Figure) -> str:
    b64 = base64.b64encode(f.png).decode()
    wide = ' class="wide"' if f.width > _WIDE_PX else ""
    return (
        f'<figure{wide}><img alt="{html.escape(f.name)}" width="{f.width}" '
        f'height="{f.height}" src="data:image/png;base64,{b64}">'
        f"<figcaption>{_inline(f.caption)}</figcaption></figure>"
    )


def _html_block(kind: str, payload: Any) -> str:
    if kind == "file":
        return ""
    if kind == "text":
        return f"<p>{_inline(payload)}</p>"
    if kind == "lead":
        return f'<p class="lead">{_inline(payload)}</p>'
    if kind == "h3":
        return f"<h3>{_inline(payload)}</h3>"
    if kind == "list":
        return '<ul class="facts">' + "".join(f"<li>{_inline(x)}</li>" for x in payload) + "</ul>"
    if kind == "cards":
        return '<div class="cards">' + "".join(_html_card(c) for c in payload) + "</div>"
    if kind == "table":
        return _html_table(payload)
    if kind == "figures":
        return '<div class="figs">' + "".join(_html_figure(f) for f in payload) + "</div>"
    if kind == "code":
        return f"<pre>{html.escape(payload)}</pre>"
    raise ValueError(f"unknown block {kind}")


def render_html(title: str, subtitle: str, sections: Sequence[Section]) -> str:
    nav = "".join(
        f'<a href="#{html.escape(s.id)}">{html.escape(s.title)}</a>' for s in sections if s.id
    )
    out = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body><main>",
        f'<header><h1>{html.escape(title)}</h1><p class="sub">{_inline(subtitle)}</p></header>',
        f"<nav>{nav}</nav>",
    ]
    for s in sections:
        body = "\n".join(_html_block(k, p) for k, p in s.blocks)
        sid = html.escape(s.id)
        if s.collapsed:
            out.append(
                f'<section id="{sid}"><details><summary>{html.escape(s.title)}</summary>\n'
                f"{body}\n</details></section>"
            )
        else:
            out.append(f'<section id="{sid}"><h2>{html.escape(s.title)}</h2>\n{body}\n</section>')
    out.append("</main></body></html>\n")
    return "\n".join(out)


# --------------------------------------------------------------------------- Markdown
def _md(s: Any) -> str:
    """Text for the Markdown twin: ``<``, ``>`` and ``&`` escaped (no name is raw HTML), a
    link whose target is not :func:`safe_href` with its brackets escaped (shown as text)."""
    text = html.escape(str(s), quote=False)
    out, pos = [], 0
    for m in _LINK.finditer(text):
        out.append(text[pos : m.start()])
        target = html.unescape(m.group(2))
        if safe_href(target) is None:
            out.append(m.group(0).replace("[", "\\[").replace("]", "\\]").replace("(", "\\("))
        else:
            out.append(m.group(0))
        pos = m.end()
    out.append(text[pos:])
    return "".join(out)


def _md_cell(v: Any) -> str:
    return _md(fmt(v)).replace("|", "\\|").replace("\n", " ")


def _md_table(t: Table) -> list[str]:
    lines = [f"**{_md(t.caption)}**", ""] if t.caption else []
    left = set(t.text_cols) | set(t.wrap_cols) | set(t.wide_cols)
    align = ["---" if j == 0 or j in left else "---:" for j in range(len(t.columns))]
    lines.append("| " + " | ".join(_md(c).replace("|", "\\|") for c in t.columns) + " |")
    lines.append("| " + " | ".join(align) + " |")
    lines += ["| " + " | ".join(_md_cell(v) for v in r) + " |" for r in t.rows]
    lines.append("")
    lines += [f"{i}. {_md(n)}" for i, n in enumerate(t.notes, 1)]
    if t.notes:
        lines.append("")
    if t.csv:
        lines += [f"Every column: [{t.csv}]({t.csv})", ""]
    return lines


def _md_cards(cards: Sequence[Card]) -> list[str]:
    cols = ["controller", "status", *(k for k, _ in cards[0].items), "verdict"]
    lines = [f"- **{_md(c.title)}**: {_md(c.promise)}" for c in cards if c.promise]
    lines += [""] if lines else []
    lines += ["| " + " | ".join(_md(c).replace("|", "\\|") for c in cols) + " |"]
    lines.append("| " + " | ".join(["---", "---", *["---:"] * len(cards[0].items), "---"]) + " |")
    for c in cards:
        values = dict(c.items)
        cells = [
            f"**{c.title}**",
            c.badge,
            *(values.get(k, "-") for k, _ in cards[0].items),
            "; ".join(
                f"{label}: {text}"
                for label, text, _ in [(c.verdict_label, c.verdict, c.verdict_kind), *c.more]
            ),
        ]
        lines.append("| " + " | ".join(_md(x).replace("|", "\\|") for x in cells) + " |")
    links = sorted({(t, h) for c in cards for t, h in c.links}, key=lambda x: x[1])
    shown = [f"[{_md(t)}]({h})" if safe_href(h) else _md(t) for t, h in links]
    lines += ["", "Backing sections: " + ", ".join(shown), ""]
    return lines


def _md_block(kind: str, payload: Any) -> list[str]:
    if kind == "file":
        return []
    if kind in ("text", "lead"):
        return [_md(payload), ""]
    if kind == "h3":
        return [f"### {_md(payload)}", ""]
    if kind == "list":
        return [*(f"- {_md(x)}" for x in payload), ""]
    if kind == "cards":
        return _md_cards(payload)
    if kind == "table":
        return _md_table(payload)
    if kind == "figures":
        return [
            line
            for f in payload
            for line in (f"![{_md(f.caption)}]({f.name})", "", f"*{_md(f.caption)}*", "")
        ]
    if kind == "code":
        return ["```yaml", payload.rstrip("\n"), "```", ""]
    raise ValueError(f"unknown block {kind}")


def render_markdown(
    title: str, subtitle: str, sections: Sequence[Section]
) -> tuple[str, dict[str, bytes]]:
    """The Markdown twin (GitHub-flavoured) and the figure files it links, by name."""
    lines = [f"# {_md(title)}", "", _md(subtitle), ""]
    lines += [" · ".join(f"[{_md(s.title)}](#{s.id})" for s in sections if s.id), ""]
    files: dict[str, bytes] = {}
    for s in sections:
        lines.append(f'<a id="{html.escape(s.id)}"></a>')
        if s.collapsed:
            lines += ["", f"<details><summary><b>{_md(s.title)}</b></summary>", ""]
        else:
            lines += ["", f"## {_md(s.title)}", ""]
        for kind, payload in s.blocks:
            lines += _md_block(kind, payload)
        if s.collapsed:
            lines += ["</details>", ""]
        files.update(s.files())
    return "\n".join(lines) + "\n", files


# --------------------------------------------------------------------------- stage PNGs
def stage_pngs(folder: Path) -> list[Path]:
    """The PNGs a stage wrote (not those of hidden or nested temporary folders), sorted."""
    return sorted(
        p
        for p in folder.rglob("*.png")
        if not any(q.startswith(".") for q in p.relative_to(folder).parts)
    )


def figure_of(run_dir: Path, path: Path, caption: str, counter: list[int]) -> Figure:
    """A stage's PNG as a report figure, named ``figNN_<folder>_<file>`` (unique, ordered)."""
    counter[0] += 1
    rel = path.relative_to(run_dir).as_posix()
    return Figure(f"fig{counter[0]:02d}_" + rel.replace("/", "_"), path.read_bytes(), caption)
