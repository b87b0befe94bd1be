"""The answer of an evaluation, per controller (docs/evaluation.md#which-flights).

On the flights a controller flew itself (``theorem_applies``), the theorem's verdict:
``bound_holds = max_k ||e_k|| <= gamma_nominal`` on every one, and the worst
``max ||e|| / gamma_nominal``. On recorded logs and other controllers' flights the theorem
does not apply: the verdict is the premise's (the share of samples with
``||e_k|| <= eps_e + S d_k``), which tests the error model, not the controller. A table
written before the theorem columns existed falls back to ``bound_holds`` and ``max_ratio``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from qsls.pipeline.control.status import (
    CERTIFIED,
    EXTRAPOLATED,
    FAILED,
    REFERENCE,
    RELAXED,
    Status,
)
from qsls.pipeline.evaluate.table import Evaluation

UNREAD = "its disturbance, dist(x_hat) and invariance are not read"
"""What a premise-only check (a flight the controller did not fly) leaves out: those
assumptions are about the controller's own closed loop (docs/evaluation.md)."""
CLAIMS = (CERTIFIED, EXTRAPOLATED, RELAXED)
"""Statuses whose premise is checked on flights (only ``certified`` claims the guarantee)."""


# --------------------------------------------------------------------------- the promise
def conditions_text(conditions: Mapping[str, Any] | None) -> str:
    """The calibration's conditions in words: perception, estimator, reference, flight length
    (docs/calibration.md, "One certificate per condition")."""
    c = dict(conditions or {})
    parts = []
    if c.get("perception"):
        parts.append(f"{c['perception']} perception")
    if c.get("estimator"):
        parts.append(f"the {c['estimator']} estimator")
    ref = c.get("reference")
    if isinstance(ref, Mapping) and ref.get("kind"):
        size = (
            f" of radius {ref['radius']:g} m" if isinstance(ref.get("radius"), int | float) else ""
        )
        parts.append(f"the {ref['kind']} reference{size}")
    elif isinstance(ref, str) and ref:
        parts.append(f"the reference {ref}")
    fam = c.get("family") if isinstance(c.get("family"), Mapping) else {}
    span = fam.get("mass") if fam else None
    if _ranged(span):
        assert span is not None
        parts.append(f"a vehicle of {span[0]:.4g} to {span[1]:.4g} kg")  # the stated family
    elif isinstance(c.get("vehicle"), Mapping) and c["vehicle"].get("mass"):
        parts.append(f"the {c['vehicle']['mass']:g} kg vehicle")
    for key, (what, unit, scale) in FAMILY_WORDS.items():
        span = fam.get(key) if fam else None
        if _ranged(span):
            assert span is not None
            lo, hi = (float(v) * scale for v in span)
            parts.append(f"{what} {lo:.3g} to {hi:.3g}{unit}")
    if fam and float(fam.get("center_offset") or 0.0) > 0:
        parts.append(f"its centre moved up to {float(fam['center_offset']):.3g} m")
    if fam and float(fam.get("start_offset") or 0.0) > 0:
        parts.append(f"a start up to {float(fam['start_offset']):.3g} m beside the reference")
    if fam and float(fam.get("figure8") or 0.0) > 0:
        parts.append(f"the figure-eight instead on {100 * float(fam['figure8']):.3g} % of flights")
    est = fam.get("estimator") if fam else None
    if isinstance(est, Mapping) and est:
        spans = ", ".join(f"{k} {float(v[0]):.3g} to {float(v[1]):.3g}" for k, v in est.items())
        parts.append(f"the estimator's {spans}")
    px4 = c.get("px4")
    if isinstance(px4, Mapping) and px4.get("interface") == "px4":
        parts.append("flown through PX4's attitude interface with its hover-thrust estimate")
    return ", ".join(parts) or "the conditions of its calibration flights"


FAMILY_WORDS = {
    "radius": ("a reference radius of", " m", 1.0),
    "period": ("a period of", " s", 1.0),
    "height": ("a height of", " m", 1.0),
    "wind": ("wind of", " m/s", 1.0),
    "gust": ("gusts of", " m/s", 1.0),
    "thrust_constant": ("a thrust constant of", " x nominal", 1.0),
    "sag": ("a battery sag of", " %", 100.0),
    "hover_error": ("a hover-thrust estimate off by", " %", 100.0),
}
"""How a ranged condition of the stated family reads in the promise (its words, unit, scale)."""


def _ranged(span: Any) -> bool:
    return isinstance(span, list | tuple) and len(span) == 2 and span[0] != span[1]


def _first_reason(cert: Mapping[str, Any]) -> str:
    reason = str(cert.get("status_reason") or "").strip()
    return reason.split("; ")[0] if reason else ""


def promise(cert: Mapping[str, Any]) -> str:
    """One plain sentence: what the certificate ``cert`` (its fields, as
    :meth:`~qsls.pipeline.control.artifacts.Certificate.model_dump` gives them) promises, for
    which conditions, with which probability, and what lies outside
    (docs/calibration.md#the-promise). Only ``certified`` promises anything: with probability
    at least ``1 - alpha`` a next flight in the calibrated conditions keeps the calibrated
    premise, and then ``dist(x_k) <= rho*`` and ``|d_k|_e <= gamma``."""
    name = str(cert.get("controller") or "this controller")
    status = str(cert.get("status") or "")
    cal = cert.get("calibration") or {}
    if status == REFERENCE:
        return f"{name} is the reference controller: it promises nothing, it is measured."
    if status == FAILED:
        why = _first_reason(cert)
        return f"{name} promises nothing: its checks failed{f' ({why})' if why else ''}."
    if status == CERTIFIED and cal:
        alpha = float(cal.get("alpha", math.nan))
        conf = cal.get("confidence")
        sure = (f", with confidence {float(conf):g} over the calibration draw"
                if cal.get("method") == "pac" and conf is not None else "")  # fmt: skip
        length = cal.get("duration_s") or (cal.get("conditions") or {}).get("duration_s")
        flight = f"{float(length):g} s flight" if length else "flight"
        return (
            f"With probability at least {1 - alpha:g}{sure}, a next {flight} of {name} in the "
            f"conditions it was calibrated in ({conditions_text(cal.get('conditions'))}) keeps "
            f"its premise and then stays within rho* = {float(cert['rho_star']):.3g} of the "
            f"training states, its dense perception error within gamma = "
            f"{float(cert['gamma']):.3g}; a flight in other conditions (another perception, "
            "estimator, reference or vehicle) lies outside this promise."
        )
    if status == EXTRAPOLATED:
        tested, rho = cert.get("tested_range"), cert.get("rho_star")
        reach = (f": its calibration flights reached {float(tested):.3g} from the training "
                 f"states, short of the rho* = {float(rho):.3g} its claim needs"
                 if tested is not None and rho is not None else "")  # fmt: skip
        return (
            f"{name} promises nothing yet (extrapolated{reach}); range flights that reach "
            "rho* would certify it."
        )
    why = _first_reason(cert)
    if status == RELAXED:
        return (
            f"{name} promises nothing for a next flight (relaxed{f': {why}' if why else ''}); "
            "calibrating it on flights it flies itself (qsls calibrate) can certify it."
        )
    if cert.get("robust") is False:
        return f"{name} promises nothing: it was designed without the robustness constraint."
    return f"{name} promises nothing ({status or 'no status'}{f': {why}' if why else ''})."


def controller_promises(certificates: Iterable[tuple[str, Mapping[str, Any]]]) -> dict[str, str]:
    """``{controller: its promise}`` from ``(name, certificate fields)`` pairs; a controller
    with one certificate per condition gets each one's sentence, in order, once."""
    out: dict[str, list[str]] = {}
    for name, cert in certificates:
        text = promise({**cert, "controller": cert.get("controller") or name})
        if text not in out.setdefault(name, []):
            out[name].append(text)
    return {name: " ".join(texts) for name, texts in out.items()}


@dataclass(frozen=True)
class Verdict:
    controller: str
    flights: int
    certified: bool  # has a certified bound to check
    holds: bool  # the bound held on every flight it applies to (False when not certified)
    worst_ratio: float  # max over those flights of max ||e|| / gamma_nominal
    worst_flight: str
    theorem: bool = True  # the theorem applied to at least one flight
    premise_share: float = math.nan  # premise-only rows: mean share of samples under it
    status: str = CERTIFIED
    windows_over: float = math.nan  # premise-only rows: largest share of windows over m
    broken: tuple[str, ...] = ()  # premise-only rows: the flights whose premise broke
    outside: int = 0  # rows checked against a certificate calibrated under other conditions
    outside_why: str = ""  # the first such row's reason
    relaxed: int = 0  # rows checked against a relaxed certificate, where others are not
    promise: str = ""  # what the certificate promises (:func:`promise`), said first

    def lines(self) -> list[str]:
        """The promise, then what the flights showed (:meth:`line`)."""
        return [self.promise, self.line()] if self.promise else [self.line()]

    @property
    def word(self) -> str:
        if not self.certified:
            return "no certified bound"
        if not self.theorem:
            return "premise only"
        return "holds" if self.holds else "FAILS"

    def line(self) -> str:
        n = f"{self.flights} flight{'s' if self.flights != 1 else ''}"
        if 0 < self.relaxed < self.flights:
            n += f" ({self.relaxed} of them under a relaxed certificate: no guarantee there)"
        if self.certified and not self.theorem:
            share = (
                f"{100 * self.premise_share:.1f}%" if math.isfinite(self.premise_share) else "n/a"
            )
            status = "" if self.status == CERTIFIED else f" of a {self.status} certificate"
            windows = (
                f", outlier windows over m: {100 * self.windows_over:.1f}%"
                if math.isfinite(self.windows_over) and self.windows_over > 0 else ""
            )  # fmt: skip
            broke = f"; premise broken on {', '.join(self.broken)}" if self.broken else ""
            if self.outside:
                broke += (
                    f"; {self.outside} of {self.flights} outside its calibration "
                    f"({self.outside_why})"
                )
            return (
                f"{self.controller}: {self.word}{status}, dense premise holds at {share} of "
                f"samples{windows} (not flown by it: the theorem does not apply; {UNREAD}){broke}, {n}"
            )
        ratio = f"{self.worst_ratio:.3g}" if math.isfinite(self.worst_ratio) else "n/a"
        where = f" ({self.worst_flight})" if self.worst_flight else ""
        what = "gamma_nominal" if self.theorem else "gamma"
        return f"{self.controller}: {self.word}, worst ||e||/{what} {ratio}{where}, {n}"


@dataclass(frozen=True)
class AssumptionVerdict:
    """A certified controller on its own flights: did every assumption of its guarantee hold
    (:mod:`qsls.pipeline.evaluate.assumptions`), and if not, which failed first and where."""

    controller: str
    flights: int
    n_hold: int
    first_failed: str
    worst_flight: str
    detail: str
    bound_held_all: bool
    status: Status = CERTIFIED
    outside: int = 0  # flights flown outside the conditions of the certificate's calibration
    outside_why: str = ""  # the first such flight's reason
    outside_failing: int = 0  # of the failing flights, those flown outside the calibration
    relaxed: int = 0  # flights checked against a relaxed certificate (one condition's, say)
    failing: tuple[str, ...] = ()  # every failing flight, the first (worst_flight) included
    promise: str = ""  # what the certificate promises (:func:`promise`), said first

    def lines(self) -> list[str]:
        """The promise, then what the flights showed (:meth:`line`)."""
        return [self.promise, self.line()] if self.promise else [self.line()]

    def line(self) -> str:
        n = f"{self.flights} flight{'s' if self.flights != 1 else ''}"
        if self.status == RELAXED or self.relaxed == self.flights > 0:
            n += " (relaxed premise: no guarantee claimed)"  # checked, but nothing promised
        elif self.relaxed:
            n += f" ({self.relaxed} of them under a relaxed premise: no guarantee claimed there)"
        if self.n_hold == self.flights:
            held = "held" if self.bound_held_all else "did NOT hold"
            return (
                f"{self.controller}: every assumption holds on {n}; as a consequence the "
                f"bound {held}"
            )
        failed, inside = self.flights - self.n_hold, self.flights - self.outside
        outside = (
            f"; {self.outside} of the {self.flights} flown outside its calibration "
            f"({self.outside_why}), {self.outside_failing} of the {failed} failing among them"
            + (f"; inside it {failed - self.outside_failing} of {inside} failed" if inside else "")
            if self.outside
            else ""
        )
        rest = [f for f in self.failing if f != self.worst_flight]
        also = (
            f"; also failing: {', '.join(rest[:5])}"
            + (f" and {len(rest) - 5} more (assumptions.parquet)" if len(rest) > 5 else "")
            if rest
            else ""
        )
        return (
            f"{self.controller}: FAILS on {self.flights - self.n_hold} of {n}: "
            f"{self.worst_flight}: {self.detail}{also}{outside}"
        )


def assumption_verdicts(table: pd.DataFrame) -> list[AssumptionVerdict]:
    """One :class:`AssumptionVerdict` per controller of an assumptions table."""
    out: list[AssumptionVerdict] = []
    if table is None or not len(table):
        return out
    for name, g in table.groupby("controller", sort=False):
        bad = g[~g["assumptions_hold"].astype(bool)]
        first = bad.iloc[0] if len(bad) else None
        away = _outside(g)
        out.append(
            AssumptionVerdict(
                str(name),
                len(g),
                len(g) - len(bad),
                str(first["first_failed"]) if first is not None else "",
                str(first["flight"]) if first is not None else "",
                str(first["verdict"]) if first is not None else "",
                bool(g["bound_held"].astype(bool).all()),
                outside=len(away),
                outside_why=str(away.iloc[0]) if len(away) else "",
                outside_failing=len(_outside(bad)),
                relaxed=int((g["status"] == RELAXED).sum()) if "status" in g else 0,
                failing=tuple(str(f) for f in bad["flight"]),
            )
        )
    return out


def _outside(g: pd.DataFrame) -> pd.Series:
    """The rows' non-empty ``outside_calibration`` reasons (none in an older table)."""
    away = g["outside_calibration"] if "outside_calibration" in g else pd.Series([], dtype=str)
    return away[away.fillna("").astype(str) != ""]


def _worst(g: pd.DataFrame, col: str) -> tuple[float, str]:
    ratio = pd.to_numeric(g[col], errors="coerce") if col in g else None
    if ratio is None or not ratio.notna().any():
        return math.nan, ""
    k = ratio.idxmax()
    return float(ratio[k]), str(g.loc[k, "flight"]) if "flight" in g else ""


def verdicts(table: pd.DataFrame) -> list[Verdict]:
    """One :class:`Verdict` per controller of an evaluation table, in table order."""
    out: list[Verdict] = []
    if table is None or not len(table) or "controller" not in table:
        return out
    for name, g in table.groupby("controller", sort=False):
        certified = bool(g["has_guarantee"].all()) if "has_guarantee" in g else True
        relaxed = int((g["status"] == RELAXED).sum()) if "status" in g else 0
        status = str(g["status"].iloc[0]) if "status" in g else CERTIFIED
        if 0 < relaxed < len(g):  # one condition's certificate certified, another's relaxed
            status = str(g.loc[g["status"] != RELAXED, "status"].iloc[0])
        if "status" in g:  # a reference claims no guarantee to check; a premise may be checked
            certified = certified and bool(g["status"].isin(CLAIMS).all())
        if "theorem_applies" not in g:  # an older table: the per-sample check
            worst, flight = _worst(g, "max_ratio")
            holds = (
                bool(g["bound_holds"].astype(bool).all())
                if "bound_holds" in g
                else (math.isfinite(worst) and worst <= 1.0)
            )
            out.append(Verdict(str(name), len(g), certified, holds and certified, worst, flight))
            continue
        own = g[g["theorem_applies"].astype(bool)]
        if not len(own):
            share = float(pd.to_numeric(g["frac_premise_holds"], errors="coerce").mean())
            over = (float(pd.to_numeric(g["frac_windows_over_m"], errors="coerce").max())
                    if "frac_windows_over_m" in g else math.nan)  # fmt: skip
            broken = (tuple(str(f) for f in g.loc[~g["premise_holds"].astype(bool), "flight"])
                      if "premise_holds" in g else ())  # fmt: skip
            away = _outside(g)
            out.append(Verdict(str(name), len(g), certified, False, math.nan, "", False, share,
                               status, over, broken, len(away),
                               str(away.iloc[0]) if len(away) else "", relaxed))  # fmt: skip
            continue
        worst, flight = _worst(own, "nominal_ratio")
        holds = bool(own["bound_holds"].astype(bool).all())
        mixed = int((own["status"] == RELAXED).sum()) if "status" in own else 0
        out.append(Verdict(str(name), len(own), certified, holds and certified, worst, flight,
                           status=status, relaxed=mixed))  # fmt: skip
    return out


ASSUMPTIONS_FILE = "assumptions.parquet"


def combined(
    table: pd.DataFrame, assumptions: pd.DataFrame | None
) -> list[Verdict | AssumptionVerdict]:
    """Each controller's verdict: on its own flights from the assumptions table when it has
    one there, else from the bound-check table."""
    own = assumption_verdicts(assumptions) if assumptions is not None else []
    names = {v.controller for v in own}
    rest = [v for v in verdicts(table) if v.controller not in names]
    return [*own, *rest]


def with_promises(
    found: list[Verdict | AssumptionVerdict], promises: Mapping[str, str] | None
) -> list[Verdict | AssumptionVerdict]:
    """Each verdict led by its controller's promise (``evaluation.json``'s ``promises``)."""
    from dataclasses import replace

    return [replace(v, promise=(promises or {}).get(v.controller, "")) for v in found]


def read_verdicts(folder: Path) -> list[Verdict | AssumptionVerdict]:
    """The verdicts of an evaluate stage folder, each led by its promise where the folder
    records one (empty when it holds no evaluation)."""
    if not Evaluation.exists(folder):
        return []
    f = Path(folder) / ASSUMPTIONS_FILE
    assumptions = pd.read_parquet(f) if f.is_file() else None
    ev = Evaluation.load(folder)
    return with_promises(combined(ev.rows, assumptions), ev.doc.get("promises"))
