"""The report's section on the calibrated certificates (docs/calibration.md): what each
candidate's own calibration flights gave, how far each premise quantity could grow, and how
the fresh validation flights fared against the stated ``alpha``."""

from __future__ import annotations

import math
from typing import Any

from qsls.pipeline.calibrate.summary import SUMMARY_FILE
from qsls.pipeline.control.artifacts import CERTIFICATE_FILE, Calibration, Certificate
from qsls.pipeline.control.conformal import Method, calibrated_quantile
from qsls.pipeline.core.artifacts import json_number, read_stage_json
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.report.document import Section
from qsls.pipeline.report.facts import Facts, g4, pct, status_words

QUANTITIES = ("eps", "S", "eps_w", "delta", "m")
PARTS = {"dense": "eps", "disturbance": "eps_w", "reference": "Delta", "outliers": "m"}
"""A score's parts by the premise quantity each inflates."""


def read_calibration(f: Facts) -> list[tuple[dict[str, Any], Certificate | None]]:
    """Each calibrated certificate's summary row with its certificate (None if missing)."""
    out: list[tuple[dict[str, Any], Certificate | None]] = []
    for folder in f.stages.get("calibrate", []):
        path = folder / SUMMARY_FILE
        if not path.is_file():
            continue
        fix = "run the calibration again (qsls run CONFIG --from calibrate)"
        doc = read_stage_json(folder, SUMMARY_FILE, fix)
        rows = doc.get("certificates") if isinstance(doc, dict) else None
        if not isinstance(rows, list) or not all(
            isinstance(r, dict) and set(r) >= _ROW_KEYS for r in rows
        ):
            raise InputError(f"{path}: not a calibration summary of this qsls version; {fix}")
        for row in rows:
            # null is the JSON of an unbounded lambda_hat: no inflation covers the flights
            row = {**row, "lambda_hat": json_number(row["lambda_hat"], math.inf)}
            cdir = folder / str(row["condition"]) / str(row["controller"])
            cert = Certificate.load(cdir) if (cdir / CERTIFICATE_FILE).is_file() else None
            out.append((row, cert))
    return out


_ROW_KEYS = frozenset({"controller", "condition", "status", "method", "alpha", "flights",
                       "lambda_hat", "rho_star", "tested_range", "validation_ci"})  # fmt: skip
"""The keys of a ``calibration.json`` row the section reads."""


def _tolerance(tolerances: dict[str, float], q: str) -> str:
    """A tolerance cell: the factor, or for a quantity stated as 0 the largest value."""
    if f"{q}_max" in tolerances:
        return f"stated 0; at most {g4(tolerances[f'{q}_max'])}"
    return g4(tolerances.get(q))


def _range_cell(cal: Calibration | None) -> str:
    """The range flights' calibrated quantile (the certificate's ``lambda_hat`` is the larger of
    it and the calibration flights'), with how many flew; ``-`` without range flights."""
    if cal is None or not cal.range_scores:
        return "-"
    method: Method = "pac" if cal.method == "pac" else "conformal"
    delta = 1.0 - cal.confidence if cal.confidence else 0.05
    q = calibrated_quantile(cal.range_scores, cal.alpha, method, delta)
    return f"{g4(q)} ({len(cal.range_scores)} flights, largest {g4(max(cal.range_scores))})"


def _notes(r: dict) -> list[str]:
    """A calibration row's notes: what set its ``lambda_hat``, and why it is not certified."""
    set_by = [f"lambda_hat set by the {r['lambda_set_by']}"] if r.get("lambda_set_by") else []
    return set_by + ([str(r["reason"])] if r["reason"] else [])


def section_calibration(f: Facts, counter: list[int]) -> Section | None:
    rows = read_calibration(f)
    if not rows:
        return None
    sec = Section("Calibrated certificates", id="calibration")
    sources = {str((c.calibration.conditions if c and c.calibration else {}).get("source", ""))
               for _, c in rows}  # fmt: skip
    flown = (
        "Each robust candidate's calibration flights are recorded flights of the vehicle (PX4 "
        "logs; of the stand-in vehicle where the conditions say standin), each proved flown by "
        "the candidate by replaying its log through the candidate's taps and gate, none a "
        "design flight (docs/vehicle.md). "
        if sources & {"recorded", "standin"}
        else "Each robust candidate flew its own calibration flights under the stated "
        "conditions, on seeds no design flight used. "
    )
    sec.text(
        f"{flown}A flight's score is the smallest inflation of the design "
        "premise (eps, S, eps_w, Delta, m) it satisfies; the calibrated premise is the design "
        "premise inflated by the conformal (or PAC) order statistic lambda_hat of the scores, "
        "and the candidate's fixed taps are checked against it. A new flight of the same "
        "conditions breaks the calibrated premise with probability at most alpha. Fresh "
        "validation flights then count how often it did (docs/calibration.md).",
        lead=True,
    )
    main, tol, valid = [], [], []
    for r, cert in rows:
        cal = cert.calibration if cert is not None else None
        parts = cal.parts if cal is not None else {}
        how = r["method"] + (
            f" {100 * cal.confidence:.0f}% conf." if cal and cal.confidence else ""
        )
        main.append([
            r["controller"], r["condition"], status_words(r["status"])[0],
            f"{g4(r['alpha'])} ({how}, {r['flights']} flights)", g4(r["lambda_hat"]),
            ", ".join(f"{q} {g4(parts.get(k))}" for k, q in PARTS.items() if k in parts),
            _range_cell(cal), f"{g4(r['rho_star'])} / {g4(r['tested_range'])}",
        ])  # fmt: skip
        tol.append([r["controller"], r["condition"],
                    *(_tolerance(cal.tolerances, q) if cal and cal.tolerances else "-" for q in QUANTITIES)])  # fmt: skip
        lo, hi = r["validation_ci"]
        failed = ", ".join(f"{k} {v}" for k, v in sorted(r["validation_first_failed"].items()))
        valid.append([
            r["controller"], r["condition"], r["validation_flights"], r["validation_broken"],
            f"{pct(r['validation_share'])} ({pct(lo)} to {pct(hi)})", g4(r["alpha"]),
            failed or "-", "yes" if r["validation_agrees"] else "NO",
        ])  # fmt: skip
    sec.table(
        ["controller", "condition", "status", "alpha", "lambda_hat",
         "largest ratio", "range flights", "rho* / reached"],
        main,
        "The calibration: lambda_hat inflates every premise quantity; the largest ratio over the "
        "calibration flights shows which quantity drives it; the range flights (the reference "
        "offset toward rho*, scored on every premise quantity but the reference's distance) give "
        "their own quantile, and "
        "lambda_hat is the larger of the two; rho* under the calibrated premise beside the "
        "distance the flights reached (certified needs it to reach rho*)",
        notes=[f"{r['controller']} ({r['condition']}): {n}" for r, _ in rows for n in _notes(r)],
        text_cols=[2, 3, 5, 6, 7],
    )  # fmt: skip
    if any(any(c != "-" for c in t[2:]) for t in tol):
        sec.table(
            ["controller", "condition", *(f"{q} x" for q in QUANTITIES)],
            tol,
            "Tolerances: the factor by which each calibrated premise quantity alone could grow "
            "before the robustness condition fails (m: in whole outliers; a quantity stated as 0 "
            "has no factor: the largest value it alone could take instead)",
            text_cols=list(range(2, 2 + len(QUANTITIES))),
        )
    sec.table(
        ["controller", "condition", "flights", "broke one", "share (95% CP)", "alpha",
         "first broken", "within alpha"],
        valid,
        "Validation on fresh flights: every assumption (disturbance, dist(x_hat) <= a, invariance, "
        "dense, outliers) checked against the calibrated premise; the share that broke one with "
        "its Clopper-Pearson interval, within alpha when the interval's lower end does not exceed it",
        text_cols=[4, 6, 7],
    )  # fmt: skip
    return sec
