"""The report's first screen: which controller is certified, with what guarantee, on what
premise, and did it hold; or, when nothing is feasible, why and what would be needed.

Everything here links to the section that backs it (``#controllers``, ``#heldout``,
``#error-model``, ``#sweep``, ``#findings``).
"""

from __future__ import annotations

import math
from typing import Any

from qsls.pipeline.control.status import CERTIFIED, REFERENCE, RELAXED
from qsls.pipeline.core.style import controller_colour
from qsls.pipeline.report.document import Card, Section
from qsls.pipeline.report.facts import (
    ControllerFacts as Controller,
)
from qsls.pipeline.report.facts import (
    Facts,
    approx_pct,
    assumption_rows,
    findings_list,
    first,
    g4,
    heldout_verdict,
    interval_text,
    num,
    pct,
    recorded_verdict,
    status_words,
)


# --------------------------------------------------------------------------- the premise
def chosen(value: Any, em: dict[str, Any], key: str) -> str:
    """How ``eps_e`` or ``S`` was chosen, read back from the error model: 'max', 'pXX' or ''."""
    if key == "S":
        top, pcts = first(em.get("s_slope"), "max"), first(em.get("s_slope"), "percentiles")
    else:
        top, pcts = em.get("eps_e"), em.get("eps_e_percentiles")
    v = num(value)
    if math.isnan(v):
        return ""
    if math.isclose(v, num(top), rel_tol=1e-9):
        return "max"
    for label, q in (pcts or {}).items():
        if math.isclose(v, num(q), rel_tol=1e-9):
            return str(label)
    return ""


def premise_entry(c: Controller, em: dict[str, Any], key: str) -> tuple[str, float, bool]:
    """``(how chosen, share of training data violating it, share inferred?)`` of ``key``
    (``eps_e``: samples, ``S``: pairs). Read from the certificate's ``premise`` when it has
    one; else inferred from the percentile it equals (pXX leaves about 1 - XX/100 outside)."""
    p = c.premise(key)
    how = str(first(p, "chosen", "how", "source", "choice", default="") or "")
    share = num(first(p, "violated", "violated_share", "share_violated", "violating_share"))
    if not how:
        how = chosen(c.cert.get(key), em, key)
    if not math.isnan(share):
        return how, share, False
    if how == "max":
        return how, 0.0, True
    if how.startswith("p") and how[1:].replace(".", "", 1).isdigit():
        return how, 1.0 - float(how[1:]) / 100.0, True
    return how, math.nan, True


def relaxed(c: Controller, em: dict[str, Any]) -> bool:
    """Does the certificate rest on a premise part of the training data violates?"""
    shares = [premise_entry(c, em, k)[1] for k in ("eps_e", "S")]
    return any(s > 0 for s in shares if not math.isnan(s))


def status_badge(c: Controller, em: dict[str, Any]) -> tuple[str, str]:
    words, kind = status_words(c.status)
    if c.status == CERTIFIED and "premise" not in c.cert and relaxed(c, em):
        return "relaxed premise, not certified", "warn"  # never round a relaxed premise up
    return words, kind


def _with_how(value: Any, how: str) -> str:
    return f"{g4(value)} ({how})" if how else g4(value)


# --------------------------------------------------------------------------- cards
def controller_card(f: Facts, c: Controller) -> Card:
    em = f.error_model
    badge, kind = status_badge(c, em)
    how_e, share_e, inferred_e = premise_entry(c, em, "eps_e")
    how_s, share_s, inferred_s = premise_entry(c, em, "S")
    items = [
        ("T (steps)", g4(c.cert.get("T"))),
        ("S", _with_how(c.cert.get("S"), how_s)),
        ("eps_e", _with_how(c.cert.get("eps_e"), how_e)),
        ("gamma", g4(c.cert.get("gamma"))),
    ]
    if c.cert.get("rho_star") is not None and c.status in (CERTIFIED, RELAXED):
        tested = c.cert.get("tested_range")
        items.append(("rho*", g4(c.cert["rho_star"]) + (
            f" (premise tested to {g4(tested)})" if tested is not None else "")))  # fmt: skip
    note = ""
    if (share_e > 0 or share_s > 0) and c.certified:
        approx = inferred_e or inferred_s
        note = (
            f"Outside the premise: {approx_pct(share_e, approx, 'an untested share')} of "
            f"training samples (eps_e), {approx_pct(share_s, approx, 'an untested share')} of "
            "left-out samples (S)."
        )
    v = heldout_verdict(f, c)
    links = [("certificate", "#controllers")]
    if v.n_flights:
        links += [("flights", "#heldout"), ("figures", "#figures")]
    rec = recorded_verdict(f, c)
    more = [("Held-out recorded flights", rec.text, rec.kind)] if rec is not None else []
    # deferred: evaluate.verdict loads pandas, which a run with nothing to do must not import
    from qsls.pipeline.evaluate.verdict import promise

    return Card(
        c.name, controller_colour(c.name), badge, kind, items, v.text, v.kind, links, note,
        "Flown flights", more, promise({**c.cert, "controller": c.name}),
    )  # fmt: skip


# --------------------------------------------------------------------------- lines
def lead_sentence(f: Facts) -> str:
    em = f.error_model
    names = [c.name for c in f.controllers]
    plain = [c.name for c in f.controllers if c.certified and not relaxed(c, em)]
    rel = [c.name for c in f.controllers
           if c.status == RELAXED or (c.certified and relaxed(c, em))]  # fmt: skip
    parts = [f"{len(names)} controller{'s' * (len(names) != 1)} synthesized"]
    if plain:
        parts.append(f"certified: {', '.join(plain)}")
    if rel:
        parts.append(f"on a relaxed premise, not certified: {', '.join(rel)}")
    if not plain and not rel:
        parts.append("none certified")
    held = [heldout_verdict(f, c) for c in f.controllers if c.certified]
    flown = [v for v in held if v.n_flights]
    text = "; ".join(parts) + "."
    if flown:
        n = sum(v.n_flights for v in flown)
        ok = sum(v.n_hold for v in flown)
        if all(assumption_rows(f, c.name) is not None for c in f.controllers if c.certified):
            text += (
                f" On the flights the certified controllers flew themselves, every assumption "
                f"of the guarantee held on {ok} of {n} ([flown flights](#findings))."
            )
        else:
            worst = max(v.worst_ratio for v in flown)
            what = "gamma_nominal" if all(v.theorem for v in flown) else "gamma(d)"
            text += (
                f" On the flights the certified controllers flew themselves, the bound held "
                f"on {ok} of {n} (worst max ||e|| / {what} = {g4(worst)}; "
                "[flown flights](#heldout))."
            )
    return text


def error_model_line(f: Facts) -> str:
    em = f.error_model
    slope = em.get("s_slope") or {}
    line = f"Error model: eps_e max {g4(em.get('eps_e'))}, S max {g4(slope.get('max'))}"
    used = [c for c in f.controllers if c.status != REFERENCE] or f.controllers
    if used:
        c = used[0]
        how_e, share_e, inf_e = premise_entry(c, em, "eps_e")
        how_s, share_s, inf_s = premise_entry(c, em, "S")
        line += (
            f"; used: eps_e {_with_how(c.cert.get('eps_e'), how_e)}, "
            f"S {_with_how(c.cert.get('S'), how_s)}; training data outside the premise: "
            f"{approx_pct(share_e, inf_e, 'an untested share')} of samples (eps_e), "
            f"{approx_pct(share_s, inf_s, 'an untested share')} of left-out samples (S)"
        )
    line += f"; radius r {g4(em.get('radius'))}, {em.get('n_samples', '?')} samples"
    return line + " ([error model](#error-model))."


def s_max_line(f: Facts) -> str:
    """The largest feasible S at each horizon T: the best over the sweep's other settings
    (radius, eps_e, ...), labelled by the setting that gives it; a negative or -inf value
    (infeasible even at S = 0) is said in words."""
    sm, sw = f.s_max, f.sweep
    parts = []
    if sm is not None and len(sm) and "s_max" in sm:
        keys = [k for k in ("eps_e", "radius", "eps_w", "delta") if k in sm]
        fixed = [k for k in keys if sm[k].nunique(dropna=False) == 1]
        varying = [k for k in keys if k not in fixed]
        head = ", ".join(f"{k} {g4(sm[k].iloc[0])}" for k in fixed)
        items = []
        for t, group in sm.groupby("T"):
            values = group["s_max"].astype(float)
            if values.isna().all():
                items.append(f"- at T = {int(t)}")
                continue
            row = group.loc[values.idxmax()]
            best = float(row["s_max"])
            text = "none (infeasible even at S = 0)" if best < 0 else g4(best)
            at = ", ".join(f"{k} {g4(row[k])}" for k in varying)
            items.append(f"{text} at T = {int(t)}" + (f" ({at})" if at and best >= 0 else ""))
        parts.append(f"Largest feasible S{f' ({head})' if head else ''}: " + ", ".join(items))
    if sw is not None and len(sw) and "feasible" in sw:
        parts.append(f"{int(sw['feasible'].sum())} of {len(sw)} sweep points feasible")
    return "; ".join(parts) + " ([sweep](#sweep))." if parts else ""


def findings_lines(f: Facts) -> list[str]:
    out = []
    for item in findings_list(f):
        ci = item.get("ci")
        effect = ""
        if item.get("effect") is not None:
            iv = interval_text(ci, item.get("n_seeds"))
            effect = f" (effect {g4(item['effect'])}, {'95% CI ' if ' to ' in iv else ''}{iv})"
        out.append(f"Finding {item['id']}, {item['claim']}: **{item['verdict']}**{effect}")
    return out


def _effect(item: dict[str, Any]) -> str:
    """``effect [lo, hi]`` of a finding (or of one half / the whole flight)."""
    if not item or item.get("effect") is None:
        return "-"
    iv = interval_text(item.get("ci"), item.get("n_seeds"))
    return g4(item["effect"]) + (f" [{iv.replace(' to ', ', ')}]" if " to " in iv else "")


def _half(h: dict[str, Any]) -> str:
    """One half of the seeds: its verdict, effect and seeds; a half without seeds (too few
    flights to split) says so instead of a verdict."""
    seeds = h.get("seeds") or []
    if not seeds and h.get("effect") is None:
        return "not tested: too few seeds to split in halves"
    span = f"seeds {seeds[0]}-{seeds[-1]}" if seeds else "seeds not recorded"
    return f"{h.get('verdict')}: {_effect(h)} ({span})"


def _per_controller(item: dict[str, Any]) -> str:
    """Finding 2's verdict per robust controller, finding 3's strict bound, else ``-``."""
    by = item.get("by_controller") or {}
    if by:
        return "; ".join(f"{c} {_effect(v)} {v.get('verdict', '')}" for c, v in by.items())
    sb = item.get("strict_bound") or {}
    if sb:
        parts = []
        for r in sb.get("controllers", []):
            b = r.get("bound")
            parts.append(
                f"{r['controller']} "
                + (f"bound {g4(b)}" if b is not None else
                   f"undefined (S ||Phi_xe|| = {g4(r.get('S_norm_phi_xe'))} >= 1)")
            )  # fmt: skip
        rows = sb.get("controllers", [])
        paper = [r for r in rows if r.get("paper_S_norm_phi_xe") is not None]
        if paper and all(r.get("bound_at_paper_S") is None for r in paper):
            lo = min(r["paper_S_norm_phi_xe"] for r in paper)
            hi = max(r["paper_S_norm_phi_xe"] for r in paper)
            parts.append(
                f"at the paper's S = {g4(paper[0]['paper_S'])}: S ||Phi_xe|| = {g4(lo)} to "
                f"{g4(hi)} >= 1, undefined, so the paper's 1.602 cannot come from "
                "R0 / (1 - S ||Phi_xe||) at that S"
            )
        return f"paper's strict bound R0 / (1 - S ||Phi_xe||): {sb.get('verdict')}; " + "; ".join(
            parts
        )
    return "-"


def findings_table(f: Facts, sec: Any) -> bool:
    """The paper's four findings, each with its verdict (both halves of the seeds must agree),
    each half's, the effect on all seeds and on the whole flight, per controller where the
    paper speaks of each (the report's first table); ``False`` without replicated findings."""
    items = [it for it in findings_list(f) if it.get("halves")]
    if not items:
        return False
    rows = []
    for it in items:
        hs = list(it["halves"]) + [{}] * (2 - len(it["halves"]))
        whole = it.get("whole_flight") or {}
        rows.append([
            it["id"], it["claim"], it["verdict"], _half(hs[0]) if hs[0] else "-",
            _half(hs[1]) if hs[1] else "-",
            f"{_effect(it)} ({it.get('verdict_all_seeds') or '-'})",
            f"{_effect(whole)} ({whole.get('verdict', '-')})" if whole else "-",
            _per_controller(it),
        ])  # fmt: skip
    check = f.findings.get("perception_check")
    if check:
        sec.text(f"Perception check before the findings: {check['text']}.")
    sec.table(
        ["#", "the paper's finding", "verdict (both halves)", "first half of the seeds",
         "second half", "all seeds", "whole flight (unsmoothed)", "per controller"],
        rows,
        "The paper's four findings (metrics over the circle with 1 s smoothing): reproduced or "
        "contradicted only when both halves of the seeds say so on their own ([details and the "
        "mechanism](#findings))",
        wrap_cols=[1, 7],
        text_cols=[2, 3, 4, 5, 6],
    )  # fmt: skip
    return True


def warning_lines(f: Facts) -> list[str]:
    out = []
    em = f.error_model
    for c in f.controllers:
        if c.status == CERTIFIED and "premise" not in c.cert and relaxed(c, em):
            how_e, _, _ = premise_entry(c, em, "eps_e")
            how_s, _, _ = premise_entry(c, em, "S")
            out.append(
                f"{c.name} is certified on eps_e = {how_e or g4(c.cert.get('eps_e'))} and "
                f"S = {how_s or g4(c.cert.get('S'))}: part of the training data itself lies "
                "outside that premise, so the guarantee is conditional."
            )
    sw = f.sweep
    if sw is not None and len(sw) and "radius_value" in sw and em.get("radius") is not None:
        radii = sorted({num(v) for v in sw["radius_value"]} - {num(em["radius"])})
        if radii:
            out.append(
                f"The sweep uses r = {', '.join(g4(r) for r in radii)}, but the error model's "
                f"S-slopes were fitted over pairs within r = {g4(em['radius'])}."
            )
    for ev in f.evaluations:
        t = ev.table
        if "frac_premise_holds" in t and len(t):
            bad = t[t["frac_premise_holds"].astype(float) < 1.0]
            flights = bad["flight"].nunique() if "flight" in bad else len(bad)
            if flights:
                worst = 1.0 - float(bad["frac_premise_holds"].min())
                out.append(
                    f"The premise ||e|| <= eps_e + S d did not hold throughout {flights} of "
                    f"{t['flight'].nunique()} flights in {ev.folder} (up to {pct(worst)} of "
                    "samples outside it): the error model does not fully generalize to them."
                )
        out += [f"{ev.folder}: {w}" for w in ev.warnings[:6]]
        if len(ev.warnings) > 6:
            out.append(f"{ev.folder}: {len(ev.warnings) - 6} more warnings in evaluation.json")
    return out


# --------------------------------------------------------------------------- infeasible
def infeasible_lines(f: Facts) -> list[str]:
    """Why no setting is feasible and what would be needed, with the run's numbers."""
    sw, sm, em = f.sweep, f.s_max, f.error_model
    if sw is None or not len(sw):
        return [
            "No controller in this run (no synth stage) and no sweep, so this report has no "
            "feasibility evidence; it shows the flights and the error model."
        ]
    eps = num(sw["eps_e_value"].iloc[0]) if "eps_e_value" in sw else num(em.get("eps_e"))
    r = num(sw["radius_value"].iloc[0]) if "radius_value" in sw else num(em.get("radius"))
    s_col = "S_value" if "S_value" in sw else "S"
    s_vals = sorted({num(v) for v in sw[s_col]})
    out = [
        f"**No setting is feasible**: none of the {len(sw)} points of the sweep (S from "
        f"{g4(s_vals[0])} to {g4(s_vals[-1])}, T in {', '.join(str(int(t)) for t in sorted(set(sw['T'])))}, "
        f"eps_e {g4(eps)}, r {g4(r)}) admits a robust controller, so no controller is certified."
    ]
    if sm is None or not len(sm) or "min_norm_phi_xy" not in sm:
        return out
    rows = sm.sort_values("T")
    m = {int(t): num(v) for t, v in zip(rows["T"], rows["min_norm_phi_xy"], strict=True)}
    smax = {int(t): num(v) for t, v in zip(rows["T"], rows["s_max"], strict=True)}
    t_best = max(m, key=lambda t: (smax[t], t))
    mm, sb = m[t_best], smax[t_best]
    s_lo = s_vals[0]
    em_slope = (em.get("s_slope") or {}).get("max")
    out.append(
        "Why: the robustness constraint (S + eps_e/r) ||Phi_xy|| + (eps_w ||Phi_xx H|| + Delta)/r "
        "<= 1 needs S + eps_e/r <= 1/min ||Phi_xy||, and since ||Phi_xy|| >= 1 always (unit "
        "weights), S + eps_e/r < 1 is necessary. Here min ||Phi_xy|| = "
        + ", ".join(f"{g4(v)} at T = {t}" for t, v in m.items())
        + f"; with eps_e/r = {g4(eps / r)} the smallest S in the grid gives S + eps_e/r = "
        f"{g4(s_lo + eps / r)} against 1/min ||Phi_xy|| = {g4(1 / mm)} at T = {t_best}, and the "
        f"remaining margin is taken by the a/r term. The theory's own premise (max eps_e "
        f"{g4(em.get('eps_e'))}, max S {g4(em_slope)}) gives S + eps_e/r = "
        f"{g4(num(em_slope) + num(em.get('eps_e')) / r)}."
    )
    need = (
        "What would be needed: at the data's eps_e = "
        f"{g4(eps)} and r = {g4(r)}, S at most "
        + ", ".join(f"{g4(smax[t])} at T = {t}" for t in smax)
        + f" (the grid's smallest S is {g4(s_lo)}; [largest feasible S](#sweep))."
    )
    if sb > 0 and s_lo * mm < 1:
        # the controller found at s_max, carried to S = s_lo: r >= r (1 - s_max m)/(1 - S m)
        r_need = r * (1 - sb * mm) / (1 - s_lo * mm)
        need += (
            f" Or a larger radius: the controller found at the largest feasible S would carry "
            f"S = {g4(s_lo)} at T = {t_best} from r of about {g4(r_need)} on (if its ||Phi_xy|| "
            "is the minimal one; more otherwise); the S-slope must then be refit at that radius."
        )
    else:
        need += f" Even S = 0 needs r above eps_e min ||Phi_xy|| = {g4(eps * mm)}."
    out.append(need)
    return out


# --------------------------------------------------------------------------- the section
def summary_section(f: Facts) -> Section:
    sec = Section("Summary", id="summary")
    tabled = False
    if f.controllers:
        sec.text(lead_sentence(f), lead=True)
        tabled = findings_table(f, sec)  # the report's first table: the paper's findings
        sec.cards([controller_card(f, c) for c in f.controllers])
    else:
        lines = infeasible_lines(f)
        sec.text(lines[0], lead=True)
        sec.bullets(lines[1:])
    facts = []
    if f.error_model:
        facts.append(error_model_line(f))
    if line := s_max_line(f):
        facts.append(line)
    sec.bullets(facts)
    if not tabled and not findings_table(f, sec):
        found = findings_lines(f)
        if found:
            sec.text("The paper's findings ([comparison](#findings)):")
            sec.bullets(found)
    warns = warning_lines(f)
    if warns:
        sec.text("Warnings:")
        sec.bullets(warns)
    return sec
