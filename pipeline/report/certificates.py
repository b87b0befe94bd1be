"""The report's "Controllers and certificates" section: per controller its certificate,
what keeps it from certified, the checks behind it and the premise it rests on
(docs/guarantee.md, docs/synthesis.md#the-checks-behind-a-certificate)."""

from __future__ import annotations

from typing import Any

from qsls.pipeline.control.status import (
    CERTIFIED,
    CHOSEN,
    EXTRAPOLATED,
    REFERENCE,
    RELAXED,
    UNCERTIFIED,
)
from qsls.pipeline.report.document import Section
from qsls.pipeline.report.facts import Facts, approx_pct, first, status_words
from qsls.pipeline.report.summary import premise_entry, status_badge

_STATUS_NOTES = {
    CERTIFIED: "certified: every check passed (solver, achievability <= 1e-7, realization "
    "<= 1e-8, internal stability, robustness lhs <= 1) on a premise calibrated on the "
    "controller's own flights (at least 19, alpha <= 0.1) that reached rho*.",
    EXTRAPOLATED: "extrapolated, not certified: calibrated, and the condition holds, but rho* "
    "lies beyond the distances the calibration flights reached.",
    RELAXED: "relaxed premise, not certified: the checks passed on a premise that is not "
    "calibrated for the next flight (the design flights' premise before qsls calibrate, a "
    "percentile, excluded samples or an untested S: the reason and shares below); no "
    "guarantee is claimed from it.",
    CHOSEN: "chosen, not certified: the paper mode's premise, whose S was picked by hand "
    "the way the paper did (the largest feasible S less a margin), not measured; every check "
    "passed on the taps, and no guarantee is claimed for any flight.",
    UNCERTIFIED: "no guarantee: a nominal controller whose robustness lhs exceeds 1; gamma "
    "is the formula's value, shown for comparison only.",
    REFERENCE: "reference, no guarantee: PD given as a closed loop, compared with the "
    "synthesized controllers; its norms are FIR-truncated.",
}


def reason_parts(reason: str) -> list[str]:
    """A ``status_reason``'s reasons: its ``"; "``-joined parts, each that names no quantity
    (no ``": "``, e.g. "certifiable with a second flight there") kept with the one before."""
    out: list[str] = []
    for part in reason.split("; "):
        if out and ": " not in part:
            out[-1] += "; " + part
        else:
            out.append(part)
    return out


def _controller_rows(
    f: Facts,
) -> tuple[list[list[Any]], list[list[Any]], list[list[Any]], list[list[Any]]]:
    """Per controller: the certificate row, the checks row, the premise row and (where the
    premise has one) its sparse part's row."""
    em = f.error_model
    rows: list[list[Any]] = []
    checks: list[list[Any]] = []
    premise: list[list[Any]] = []
    sparse: list[list[Any]] = []
    for c in f.controllers:
        d = c.cert
        rows.append(
            [
                c.name,
                status_badge(c, em)[0],
                d.get("T"),
                d.get("S"),
                d.get("eps_e"),
                first(d, "norm_N", "norm_phi_xy"),
                d.get("robustness_lhs"),
                d.get("gamma"),
            ]
        )
        checks.append(
            [
                c.name,
                d.get("a"),
                d.get("rho_star"),
                d.get("tested_range"),
                d.get("gamma_strict"),
                d.get("achievability_residual"),
                d.get("realization_error"),
                first(d, "solver_status", default="-"),
            ]
        )
        pe, pe_share, pe_inf = premise_entry(c, em, "eps_e")
        ps, ps_share, ps_inf = premise_entry(c, em, "S")
        prem = d.get("premise") or {}
        premise.append(
            [
                c.name,
                pe or "-",
                approx_pct(pe_share, pe_inf),
                ps or "-",
                approx_pct(ps_share, ps_inf),
                d.get("radius"),
                d.get("delta"),
                _with_source(d.get("eps_w"), prem.get("eps_w_source")),
            ]
        )
        if prem.get("m") or prem.get("measure", "full") != "full":
            sparse.append(
                [c.name, prem.get("measure", "full"), _entry_text(prem.get("m")),
                 _entry_text(prem.get("eps_o")), d.get("gate")]
            )  # fmt: skip
    return rows, checks, premise, sparse


def _with_source(value: Any, source: str | None) -> str:
    if value is None:
        return "-"
    text = f"{value:.4g}"
    if source == "input_free_residual":
        text += " (input-free residual: a lower bound)"
    elif source:
        text += f" ({source})"
    return text


def _entry_text(e: dict[str, Any] | None) -> str:
    """``value (how; share violated)`` of a premise entry, ``-`` where the premise has none."""
    if not e:
        return "-"
    share = e.get("violated")
    tail = "" if share is None else f"; {100 * share:.3g}% outside"
    return f"{e['value']:.4g} ({e['chosen']}{tail})"


def _certificates_table(f: Facts, sec: Section, rows: list[list[Any]]) -> None:
    """One row per controller: its status, the premise (S, eps_e), N, lhs and gamma, with a
    note on each status shown."""
    em = f.error_model
    seen = sorted({status_badge(c, em)[0] for c in f.controllers})
    notes = [
        n
        for key, n in _STATUS_NOTES.items()
        if any(status_words(key)[0] == s or (key == RELAXED and "relaxed" in s) for s in seen)
    ]
    sec.table(
        [
            "controller",
            "status",
            "T (steps)",
            "S",
            "eps_e",
            "N = ||W_x Phi_xy W_e^-1||",
            "robustness lhs (<= 1)",
            "gamma = eps_e + S rho*",
        ],
        rows,
        "Certificates (docs/guarantee.md): when lhs = (S + eps_e/r) N + (a + eps_o G_m)/r <= 1, "
        "the vehicle stays within rho* of the training states (next table) and the dense error "
        "below gamma",
        notes=notes,
        text_cols=[1],
    )


def _reasons_table(f: Facts, sec: Section) -> None:
    """What keeps each certificate from certified, one ``status_reason`` part a row."""
    em = f.error_model
    # one row per reason (a status_reason joins them with "; "), the prose wrapped in a wide
    # column: a whole reason on one row was a line thousands of px long, or 247 px tall wrapped
    reasons = [
        [c.name if k == 0 else "", status_badge(c, em)[0] if k == 0 else "", part]
        for c in f.controllers
        if c.cert.get("status_reason")
        for k, part in enumerate(reason_parts(str(c.cert["status_reason"])))
    ]
    if reasons:
        sec.table(
            ["controller", "status", "why (the certificate's status_reason, one reason a row)"],
            reasons,
            "What keeps each certificate from certified: which premise quantity could not be "
            "measured or tested, and what data would make it certifiable",
            text_cols=[1],
            wide_cols=[2],
        )


def section_controllers(f: Facts, counter: list[int]) -> Section | None:
    if not f.controllers:
        return None
    sec = Section("Controllers and certificates", id="controllers")
    rows, checks, premise, sparse = _controller_rows(f)
    _certificates_table(f, sec, rows)
    _reasons_table(f, sec)
    sec.table(
        [
            "controller",
            "a = eps_w N_w + Delta",
            "rho*",
            "premise tested to",
            "gamma_strict = R0/(1 - S N)",
            "achievability residual",
            "realization error",
            "solver",
        ],
        checks,
        "The a-priori distance, the region rho* beside the distance out to which the premise's S "
        "was tested on left-out flights, the paper's stricter comparison and the numerical checks",
        text_cols=[6],
    )
    sec.table(
        [
            "controller",
            "eps_e chosen",
            "samples outside",
            "S chosen",
            "left-out samples outside",
            "r",
            "Delta",
            "eps_w",
        ],
        premise,
        "The premise each guarantee rests on (shares of the training data violating it)",
        notes=[
            "Without a premise record in the certificate, a share is inferred from the "
            "percentile: pXX leaves about 1 - XX/100 of the training data outside."
        ]
        if any("premise" not in c.cert for c in f.controllers)
        else [],
    )
    if sparse:
        sec.table(
            ["controller", "measured channels", "m (outliers per T steps)", "eps_o", "gate V"],
            sparse,
            "The premise's sparse part: at most m velocity outliers (errors beyond beta) in any "
            "T steps, each within eps_o (from the gate: 2V - beta)",
            text_cols=[1, 2, 3],
        )
    return sec
