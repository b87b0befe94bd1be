"""``comparison.md``: the paper's findings paired by seed as a Markdown table, the perception
check, the mechanism per controller and condition, and the per-controller metrics
(docs/evaluation.md, The paper's findings). Text from the ``findings.json`` document; nothing is
computed here."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import pandas as pd

from qsls.pipeline.fly.findings import state_dependence_markdown
from qsls.pipeline.fly.items import num


def _effect_text(f: dict[str, Any]) -> str:
    lo, hi = f["ci"]
    eff = "n/a" if f["effect"] is None else f"{f['effect']:.3g}"
    return eff + (f" [{lo:.3g}, {hi:.3g}]" if lo is not None and hi is not None else "")


def halves_text(f: dict[str, Any]) -> str:
    """``seeds a to b: verdict (effect [CI]); ...`` of a finding's replication split."""
    out = []
    for h in f.get("halves") or []:
        s = h["seeds"]
        span = f"seeds {s[0]} to {s[-1]}" if s else "no seeds"
        out.append(f"{span}: {h['verdict']} ({_effect_text(h)})")
    return "; ".join(out) or "-"


def comparison_markdown(
    comparison: Sequence[dict[str, Any]],
    per: pd.DataFrame,
    findings: dict[str, Any] | None = None,
) -> str:
    """The findings table (paired by seed with intervals when ``findings``, the
    ``findings.json`` document, is given) and the per-controller metrics as Markdown."""
    lines = ["# qsls against the paper's findings", ""]

    def cell(v: Any) -> str:
        return str(v).replace("|", "\\|")

    if findings is not None:
        lines += findings_markdown(findings, comparison)
        pm = findings.get("paper_mode")
        if pm:
            lines += ["", f"Paper mode, finding 2's measure ({pm['metric']}, < 1: softer than PD):"]
            lines += [
                f"- {c} ({cond}): {v['effect']:.3g} [{v['ci'][0]:.3g}, {v['ci'][1]:.3g}]"
                for c, by in pm["controllers"].items()
                for cond, v in by.items()
                if v["ci"][0] is not None and v["ci"][1] is not None
            ]
        lines += state_dependence_markdown(findings.get("state_dependence"))
    else:
        lines += ["| finding (paper) | qsls | agrees |", "|---|---|---|"]
        lines += [
            f"| {cell(c['finding'])} | {cell(c['qsls'])} | {cell(c['agrees'])} |"
            for c in comparison
        ]
    cols = [
        "condition", "controller", "flights", "crashed", "tracking_rms_m", "tracking_max_m",
        "perception_error_rms", "perception_error_max", "control_effort_rms",
        "control_smoothness_rms", "smoothness_vs_pd", "reaction_vs_pd", "angular_rate_rms",
        "blur_px_mean", "features_per_frame", "tracking_rms_m_circle",
        "perception_error_rms_circle", "gamma_strict", "frac_under_gamma", "max_ratio",
    ]  # fmt: skip
    cols = [c for c in cols if c in per.columns]
    lines += ["", "## Per controller and condition (mean over seeds; maxima: max)", ""]
    lines += ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in per[cols].itertuples(index=False):
        lines.append(
            "| " + " | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in r) + " |"
        )
    return "\n".join(lines) + "\n"


def findings_markdown(doc: dict[str, Any], comparison: Sequence[dict[str, Any]] = ()) -> list[str]:
    """The findings as a Markdown table (``| 1. claim | effect [CI] | verdict | qsls | ... |``),
    with the point comparison (means over seeds, ``agrees``) of the same finding beside."""

    def cell(v: Any) -> str:
        return str(v).replace("|", "\\|")

    point = {str(c["finding"]).partition(".")[0]: c for c in comparison}
    lines = [
        f"Paired by seed ({doc.get('n_seeds', 0)} seeds): {doc.get('method', '')}.",
        "",
        "| finding (paper) | effect [95% CI] | verdict (both halves) | halves | qsls "
        "| means over seeds (agrees) |",
        "|---|---|---|---|---|---|",
    ]
    for f in doc.get("findings", []):
        c = point.get(str(f["id"]))
        means = f"{c['qsls']} ({c['agrees']})" if c else "-"
        lines.append(
            f"| {f['id']}. {cell(f['claim'])} | {_effect_text(f)} (paper: "
            f"{cell(f['paper_direction'])}) | {f['verdict']} | {cell(halves_text(f))} "
            f"| {cell(f.get('mechanism', f['detail']))} | {cell(means)} |"
        )
    check = doc.get("perception_check")
    if check:
        lines += ["", f"Perception check: {check['text']}."]
    mech = doc.get("mechanism") or []
    if mech:
        lines += ["", "The mechanism, per controller and condition (means over seeds):", ""]
        keys = [k for k in mech[0] if k not in ("controller", "condition")]
        lines += [
            "| controller | condition | " + " | ".join(keys) + " |",
            "|---|---|" + "---|" * len(keys),
        ]
        for r in mech:
            vals = [num(float(r[k])) if isinstance(r[k], int | float) else "-" for k in keys]
            lines.append(f"| {r['controller']} | {r['condition']} | " + " | ".join(vals) + " |")
    rms = doc.get("degraded_perception_rms") or {}
    if rms:
        lines += ["", "Degraded perception, ||e||_inf RMS per controller (mean [95% CI]):", ""]
        for name, v in rms.items():
            lo, hi = v["ci"]
            ci = f" [{lo:.4g}, {hi:.4g}]" if lo is not None and hi is not None else ""
            lines.append(f"- {name}: {v['mean']:.4g}{ci}")
    return lines
