"""What the report says, read once from a run folder, tolerant of missing or older keys.

Every stage's files are read here (certificates, error model, sweep tables, the bound
check, the flown comparison and its findings); the summary and the sections only format.
Certificates and the error model are read through their typed loaders
(:meth:`~qsls.pipeline.control.artifacts.Certificate.load`,
:func:`~qsls.pipeline.errormodel.model.load_error_model`), so a file this qsls cannot read
stops the report with the loader's one-line error; the sections see their fields as
mappings. In the evaluation tables newer keys are preferred where they exist
(``bound_holds`` against ``gamma_nominal``, ``fly/findings.json``) and older ones used
otherwise.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from qsls.pipeline.control.status import (
    CERTIFIED,
    CHOSEN,
    EXTRAPOLATED,
    FAILED,
    REFERENCE,
    RELAXED,
    SOLVER_INACCURATE,
    UNCERTIFIED,
    Status,
)
from qsls.pipeline.core.artifacts import read_manifest
from qsls.pipeline.errormodel.model import ERROR_MODEL_FILE, load_error_model

if TYPE_CHECKING:
    from qsls.pipeline.control.certificate import Certificate

RUN_FILE = "run.json"


def first(d: Any, *keys: str, default: Any = None) -> Any:
    """The first of ``keys`` present in mapping ``d`` with a value other than None."""
    if not isinstance(d, dict):
        return default
    for k in keys:
        if d.get(k) is not None:
            return d[k]
    return default


def num(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def g4(v: Any) -> str:
    """A number to 3-4 significant digits for prose ('-' when missing)."""
    x = num(v)
    if math.isnan(x):
        return "-"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.3g}"


def pct(v: Any) -> str:
    x = num(v)
    if math.isnan(x):
        return "-"
    return f"{100 * x:.1f}%" if 0 < x < 0.01 else f"{100 * x:.0f}%"


def approx_pct(v: Any, inferred: bool, unknown: str = "-") -> str:
    """:func:`pct`, marked ``~`` when inferred from how the number was chosen; ``unknown``
    when there is no share at all (a number chosen by hand: no data tested it)."""
    return unknown if math.isnan(num(v)) else "~" * inferred + pct(v)


def _json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_bytes())
    except ValueError:  # not JSON, or not UTF-8
        return {}
    return doc if isinstance(doc, dict) else {}


def _parquet(path: Path) -> Any:
    import pandas as pd

    return pd.read_parquet(path) if path.is_file() else None


# --------------------------------------------------------------------------- status words
STATUS_WORDS: dict[Status, tuple[str, str]] = {
    CERTIFIED: ("certified", "ok"),
    EXTRAPOLATED: ("extrapolated beyond the tested range, not certified", "warn"),
    RELAXED: ("relaxed premise, not certified", "warn"),
    CHOSEN: ("premise chosen by hand (the paper's), not measured", "warn"),
    UNCERTIFIED: ("no guarantee", "muted"),
    REFERENCE: ("reference, no guarantee", "muted"),
    FAILED: ("failed", "bad"),
    SOLVER_INACCURATE: ("solver inaccurate", "bad"),
}


def status_words(status: Any) -> tuple[str, str]:
    """A certificate's status in plain words and its badge kind (ok/warn/bad/muted)."""
    return STATUS_WORDS.get(status, (str(status or "unknown").replace("_", " "), "bad"))


# --------------------------------------------------------------------------- the facts
@dataclass(frozen=True)
class ControllerFacts:
    name: str
    folder: str  # synth folder, relative to the run
    cert: dict[str, Any]
    """The certificate's fields (:meth:`Certificate.model_dump`)."""

    @classmethod
    def of(cls, certificate: Certificate, folder: str, fallback_name: str) -> ControllerFacts:
        name = certificate.controller or fallback_name
        return cls(name, folder, certificate.model_dump())

    @property
    def status(self) -> str:
        return str(self.cert.get("status", "unknown"))

    @property
    def certified(self) -> bool:
        return self.status == CERTIFIED

    def premise(self, key: str) -> dict[str, Any]:
        """``premise[key]`` as a mapping (value, how chosen, violated share), or empty."""
        p = first(self.cert, "premise", default={})
        entry = p.get(key) if isinstance(p, dict) else None
        if isinstance(entry, dict):
            return entry
        return {"value": entry} if entry is not None else {}


@dataclass(frozen=True)
class EvalTable:
    folder: str  # relative to the run
    kind: str  # "evaluate" (recorded held-out flights) or "fly" (flown by the controllers)
    table: Any  # pandas DataFrame
    warnings: list[str]


@dataclass
class Facts:
    run_dir: Path
    info: dict[str, Any]
    stages: dict[str, list[Path]]
    error_model: dict[str, Any] = field(default_factory=dict)
    error_model_folder: str = ""
    controllers: list[ControllerFacts] = field(default_factory=list)
    sweep: Any = None
    s_max: Any = None
    sweep_options: dict[str, Any] = field(default_factory=dict)
    evaluations: list[EvalTable] = field(default_factory=list)
    per_controller: Any = None
    comparison: list[dict[str, Any]] = field(default_factory=list)
    findings: dict[str, Any] = field(default_factory=dict)
    fly_folder: str = ""

    @property
    def name(self) -> str:
        return str(self.info.get("name", self.run_dir.name))

    def rel(self, folder: Path) -> str:
        return folder.relative_to(self.run_dir).as_posix()


def read_facts(run_dir: Path, stages: dict[str, list[Path]]) -> Facts:
    # deferred: scipy and pandas; qsls run reads RUN_FILE here when it validates a config
    from qsls.pipeline.control.artifacts import CERTIFICATE_FILE, Certificate
    from qsls.pipeline.control.sweep import S_MAX_FILE, SWEEP_FILE

    info = _json(run_dir / RUN_FILE)
    f = Facts(run_dir=run_dir, info=info, stages=stages)
    for folder in stages.get("fit", []):
        if not f.error_model and (folder / ERROR_MODEL_FILE).is_file():
            f.error_model = load_error_model(folder).model_dump()
            f.error_model_folder = f.rel(folder)
    for folder in stages.get("synth", []):
        calibrated = _calibrated_folders(stages)
        for cert_file in sorted(folder.glob(f"*/{CERTIFICATE_FILE}")):
            # a calibrated certificate is the controller's (docs/calibration.md)
            own = calibrated.get(cert_file.parent.name)
            where = own.parent if own is not None else folder
            cert = Certificate.load(own if own is not None else cert_file)
            f.controllers.append(ControllerFacts.of(cert, f.rel(where), cert_file.parent.name))
    for folder in stages.get("sweep", []):
        if f.sweep is None:
            f.sweep = _parquet(folder / SWEEP_FILE)
            f.s_max = _parquet(folder / S_MAX_FILE)
            f.sweep_options = read_manifest(folder).get("options") or {}
    for folder in [*stages.get("evaluate", []), *stages.get("fly", [])]:
        _read_evaluation(f, folder)
    return f


def _calibrated_folders(stages: dict[str, list[Path]]) -> dict[str, Path]:
    """Controller name -> its calibrated certificate's folder, in the calibration's first
    condition (the one the run's flights are checked against), from ``calibration.json``."""
    # deferred: scipy and pandas; qsls run reads RUN_FILE here when it validates a config
    from qsls.pipeline.calibrate.summary import SUMMARY_FILE
    from qsls.pipeline.control.artifacts import CERTIFICATE_FILE

    out: dict[str, Path] = {}
    for folder in stages.get("calibrate", []):
        doc = _json(folder / SUMMARY_FILE)
        for row in doc.get("certificates", []) if isinstance(doc, dict) else []:
            first = doc["certificates"][0]["condition"]
            cdir = folder / str(row["condition"]) / str(row["controller"])
            if row["condition"] == first and (cdir / CERTIFICATE_FILE).is_file():
                out.setdefault(str(row["controller"]), cdir)
    return out


def _read_evaluation(f: Facts, folder: Path) -> None:
    # deferred: scipy and pandas; qsls run reads RUN_FILE here when it validates a config
    from qsls.pipeline.evaluate.table import Evaluation
    from qsls.pipeline.fly.items import FINDINGS_FILE
    from qsls.pipeline.fly.tables import PER_CONTROLLER_TABLE

    ev = Evaluation.load(folder) if Evaluation.exists(folder) else None
    doc = ev.doc if ev is not None else {}
    table = ev.rows if ev is not None else None
    fly = doc.get("mode") == "fly" or (folder / PER_CONTROLLER_TABLE).is_file()
    if table is not None:
        warnings = [str(w) for w in doc.get("warnings") or []]
        f.evaluations.append(
            EvalTable(f.rel(folder), "fly" if fly else "evaluate", table, warnings)
        )
    if fly:
        f.fly_folder = f.fly_folder or f.rel(folder)
        if f.per_controller is None:
            f.per_controller = _parquet(folder / PER_CONTROLLER_TABLE)
        f.comparison = f.comparison or list(doc.get("comparison") or [])
        f.findings = f.findings or _json(folder / FINDINGS_FILE)


# --------------------------------------------------------------------------- verdicts
@dataclass(frozen=True)
class HeldoutVerdict:
    text: str
    kind: str  # ok | warn | bad | muted
    n_flights: int = 0
    n_hold: int = 0
    worst_ratio: float = math.nan
    theorem: bool = False  # checked against gamma_nominal (the theorem on the flight)


def own_rows(f: Facts, name: str) -> tuple[Any, bool]:
    """The bound-check rows of flights flown by controller ``name`` and whether they carry
    the theorem-level columns (``gamma_nominal``)."""
    for ev in f.evaluations:
        t = ev.table
        if "flown_by" in t and "controller" in t:
            rows = t[(t["controller"] == name) & (t["flown_by"] == name)]
            if len(rows):
                return rows, "gamma_nominal" in t
    return None, False


def recorded_verdict(f: Facts, c: ControllerFacts) -> HeldoutVerdict | None:
    """The premise check on the recorded held-out flights (the ``evaluate`` stage): the
    theorem does not apply to a flight the controller did not fly, so this tests the error
    model there, apart from the verdict on the flights it flew."""
    # deferred: scipy and pandas; qsls run reads RUN_FILE here when it validates a config
    from qsls.pipeline.evaluate.verdict import UNREAD, verdicts

    for ev in f.evaluations:
        t = ev.table
        if ev.kind != "evaluate" or "controller" not in t:
            continue
        rows = t[t["controller"] == c.name]
        if "flown_by" in rows:
            rows = rows[rows["flown_by"].fillna("").astype(str) != c.name]
        if not len(rows):
            continue
        (v,) = verdicts(rows)
        n = f"{v.flights} flight{'s' * (v.flights != 1)}"
        if not v.certified:
            return HeldoutVerdict(f"no guarantee to check ({n})", "muted", v.flights)
        if v.theorem:  # an older table without the theorem columns: the per-sample check
            return HeldoutVerdict(
                f"per-sample bound {'held' if v.holds else 'FAILED'}; worst max ||e|| / "
                f"gamma(d) = {g4(v.worst_ratio)} ({n})",
                "ok" if v.holds else "bad",
                v.flights,
            )
        share = f"{100 * v.premise_share:.1f}%" if math.isfinite(v.premise_share) else "n/a"
        return HeldoutVerdict(
            f"premise ||e_k|| <= eps_e + S d_k holds at {share} of samples ({n}; not flown "
            f"by it: the theorem does not apply; {UNREAD})",
            "muted",
            v.flights,
        )
    return None


def assumption_rows(f: Facts, name: str) -> Any:
    """The fly stage's assumption checks of controller ``name`` (None without them)."""
    import pandas as pd

    # deferred: scipy and pandas; qsls run reads RUN_FILE here when it validates a config
    from qsls.pipeline.evaluate.verdict import ASSUMPTIONS_FILE

    if not f.fly_folder:
        return None
    path = f.run_dir / f.fly_folder / ASSUMPTIONS_FILE
    if not path.is_file():
        return None
    a = pd.read_parquet(path)
    rows = a[a["controller"] == name] if len(a) else a
    return rows if len(rows) else None


def _outside_text(rows: Any) -> str:
    """Which of the flights lay outside the certificate's calibration and why (the first
    flight's conditions, in the fly table's words), or nothing when every one lay inside."""
    if "outside_calibration" not in rows:
        return ""
    away = rows[rows["outside_calibration"].fillna("").astype(str) != ""]
    if not len(away):
        return ""
    first = away.iloc[0]
    return (
        f"; {len(away)} of {len(rows)} flown outside its calibration "
        f"({first['flight']}: {first['outside_calibration']})"
    )


def heldout_verdict(f: Facts, c: ControllerFacts) -> HeldoutVerdict:
    """Did the guarantee hold on the flights this controller flew itself? Every assumption
    checked on its own log where the fly stage has them, else the bound check's verdict."""
    a = assumption_rows(f, c.name)
    if a is not None:
        n = len(a)
        ok = int((a["assumptions_hold"].astype(bool) & a["bound_held"].astype(bool)).sum())
        bad = a[~(a["assumptions_hold"].astype(bool) & a["bound_held"].astype(bool))]
        text = f"every assumption held on {ok} of {n} own flights"
        if "estimator" in a and a["estimator"].nunique() > 1:  # every estimator counted
            text += " (" + ", ".join(
                f"{est} {len(g)}" for est, g in a.groupby("estimator", sort=False)
            ) + ")"  # fmt: skip
        if len(bad):
            named = [f"{r['flight']} ({r['first_failed'] or 'bound'})" for _, r in bad.iterrows()]
            more = f" and {len(named) - 6} more" if len(named) > 6 else ""
            text += "; failed: " + ", ".join(named[:6]) + more
        text += _outside_text(a)
        if not c.certified:
            text += f" ({c.status} premise: no guarantee claimed)"
        return HeldoutVerdict(text, "ok" if ok == n else "bad", n, ok, float(n - ok), True)
    rows, theorem = own_rows(f, c.name)
    if rows is None:
        if any(ev.kind == "fly" for ev in f.evaluations):
            return HeldoutVerdict("not flown", "muted")
        return HeldoutVerdict("not flown (the theorem applies to its own flights only)", "muted")
    n = len(rows)
    if theorem:
        gamma = rows["gamma_nominal"].astype(float)
        ratio = (rows["max_error_norm"].astype(float) / gamma).max()
    else:
        ratio = float(rows["max_ratio"].max()) if "max_ratio" in rows else math.nan
    holds = (
        int(rows["bound_holds"].fillna(False).astype(bool).sum()) if "bound_holds" in rows else 0
    )
    guaranteed = bool(rows["has_guarantee"].all()) if "has_guarantee" in rows else c.certified
    what = "max ||e|| / gamma_nominal" if theorem else "max ||e|| / gamma(d)"
    if not guaranteed:
        return HeldoutVerdict(
            f"no guarantee to check; {what} = {g4(ratio)} on {n} flight{'s' * (n > 1)}",
            "muted",
            n,
            holds,
            float(ratio),
            theorem,
        )
    kind = "ok" if holds == n else "bad"
    scope = "" if theorem else " (per-sample check)"
    return HeldoutVerdict(
        f"bound held on {holds} of {n} own flights{scope}; worst {what} = {g4(ratio)}",
        kind,
        n,
        holds,
        float(ratio),
        theorem,
    )


def interval_text(ci: Any, n_seeds: Any = None) -> str:
    """A finding's 95% interval as text: ``a to b``; with one seed there is none to give
    (``one seed: no interval``, not ``- to -``)."""
    if isinstance(ci, list | tuple) and len(ci) == 2 and None not in ci:
        lo, hi = (float(v) for v in ci)
        if math.isfinite(lo) and math.isfinite(hi):
            return f"{g4(lo)} to {g4(hi)}"
    return "one seed: no interval" if n_seeds == 1 else "no interval"


def findings_list(f: Facts) -> list[dict[str, Any]]:
    """The paper's findings as ``{id, claim, verdict, effect, ci, detail}`` from
    ``findings.json`` (issue 13's schema) or, failing that, the comparison table."""
    out: list[dict[str, Any]] = []
    for item in f.findings.get("findings") or []:
        out.append(
            {
                "id": item.get("id", len(out) + 1),
                "claim": str(item.get("claim", "")),
                "verdict": str(item.get("verdict", "")),
                "effect": item.get("effect"),
                "ci": item.get("ci"),
                "n_seeds": item.get("n_seeds", f.findings.get("n_seeds")),
                "detail": str(first(item, "mechanism", "detail", "qsls", default="")),
                "halves": item.get("halves") or [],
                "verdict_all_seeds": item.get("verdict_all_seeds"),
                "whole_flight": item.get("whole_flight"),
                "by_controller": item.get("by_controller"),
                "strict_bound": item.get("strict_bound"),
            }
        )
    if out:
        return out
    for i, c in enumerate(f.comparison, 1):
        claim = str(c.get("finding", ""))
        head, _, rest = claim.partition(". ")
        out.append(
            {
                "id": int(head) if head.isdigit() else i,
                "claim": rest if head.isdigit() else claim,
                "verdict": str(c.get("agrees", "")),
                "effect": None,
                "ci": None,
                "detail": str(c.get("qsls", "")),
            }
        )
    return out
