"""``qsls verify DIR``: a calibrated certificate recomputed from its evidence (docs/verify.md).

Every reader already recomputes a certificate's numbers from its taps and its premise
(:func:`qsls.pipeline.control.artifacts.load_controller_dir`). ``verify`` also re-reads the
flights behind a calibration: for each controller folder of a calibration output (or one
controller folder inside it),

- every tick log its record lists (``calibration.evidence``) is read and its sha256 checked;
- every calibration and range flight's score ``lambda_f`` is recomputed by the calibration's
  own scoring (:func:`~qsls.pipeline.calibrate.core.score_flight`,
  :func:`~qsls.pipeline.calibrate.core.range_score`) under the design premise the record
  states, against the training states of the error model the calibration read;
- ``lambda_hat``, its rank, the tested range (the largest ``dist(x_k)`` within ``r``) and the
  status come from the calibration's own decision
  (:func:`~qsls.pipeline.calibrate.core.decide`) on the recomputed scores;
- the conditions the logs carry: each flight's perception condition (its tick log's metadata,
  and the folder the certificate sits in), the controller that flew it (its ``controller.npz``
  sha256), the flights' seeds, and the flight length (ticks times the tick, to within a tick);
- the innovation monitor's statistic of every calibration flight and their quantile
  (docs/monitor.md#the-calibrated-mode).

Each difference is one :class:`Difference` (field, stored, recomputed); none: verified.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from qsls.pipeline.calibrate import core
from qsls.pipeline.calibrate.core import Rule, Scores
from qsls.pipeline.calibrate.flights import PERCEPTION_ATTR
from qsls.pipeline.calibrate.stage import SCORES_FILE, STAGE
from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    Calibration,
    ControllerDir,
    differs,
    load_controller_dir,
)
from qsls.pipeline.control.guarantee import a_value
from qsls.pipeline.control.innovation import monitor_calibration
from qsls.pipeline.control.monitor import hover_input, sound_innovation_of
from qsls.pipeline.core.artifacts import MANIFEST, read_manifest, sha256_file
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.ticks import TickLog
from qsls.pipeline.errormodel.model import load_error_model, resolve_model
from qsls.pipeline.evaluate.assumptions import CertifiedPremise
from qsls.pipeline.evaluate.certified import (
    check_model_hash,
    load_controller_bound,
    premise_of,
)
from qsls.pipeline.evaluate.training import TrainingData, load_training

VERIFIED = "verified"


@dataclass(frozen=True)
class Difference:
    """One thing a certificate states that its evidence does not give."""

    where: str
    """The controller folder (relative to the verified folder; ``.`` for itself)."""
    field: str
    stored: str
    recomputed: str

    def line(self) -> str:
        return f"{self.where}: {self.field}: stored {self.stored}, recomputed {self.recomputed}"


@dataclass(frozen=True)
class VerifyResult:
    """What ``verify`` read and what differed."""

    folder: Path
    certificates: tuple[str, ...]
    flights: int
    """Tick logs re-read and recomputed."""
    differences: tuple[Difference, ...]

    @property
    def verified(self) -> bool:
        return not self.differences

    def lines(self) -> list[str]:
        """``verified ...`` or one line per difference."""
        if self.verified:
            return [
                f"{VERIFIED}: {len(self.certificates)} certificate(s), {self.flights} tick logs "
                "re-read; every score, lambda_hat, the tested range, the conditions and the "
                "certificate's numbers recomputed: match"
            ]
        return [d.line() for d in self.differences]


def _shown(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.10g}"
    return str(v)


def controller_folders(folder: Path) -> tuple[Path | None, list[Path]]:
    """``(calibration output or None, controller folders)`` of ``folder``: a calibration
    output stands for every ``<condition>/<controller>/`` inside it; a controller folder for
    itself, its calibration output two levels up when there is one."""
    folder = Path(folder)
    if (folder / CERTIFICATE_FILE).is_file():
        root = folder.parent.parent
        return (root if _is_calibration(root) else None), [folder]
    if _is_calibration(folder):
        found = sorted(p.parent for p in folder.glob(f"*/*/{CERTIFICATE_FILE}"))
        if not found:
            raise InputError(f"verify: {folder} is a calibration output with no certificate")
        return folder, found
    raise InputError(
        f"verify: {folder} is neither a calibration output ('qsls calibrate') nor a controller "
        f"folder (no {CERTIFICATE_FILE})"
    )


def _is_calibration(folder: Path) -> bool:
    if not (folder / MANIFEST).is_file():
        return False
    try:
        return read_manifest(folder).get("stage") == STAGE
    except InputError:
        return False


def verify(folder: Path) -> VerifyResult:
    """Recompute every controller folder of ``folder`` from its evidence (module docstring)."""
    folder = Path(folder)
    root, folders = controller_folders(folder)
    diffs: list[Difference] = []
    flights = 0
    training = _training(root, diffs)
    for f in folders:
        where = f.relative_to(root).as_posix() if root is not None else "."
        n, more = _one(f, where, root, training)
        flights += n
        diffs += more
    return VerifyResult(folder, tuple(f.name for f in folders), flights, tuple(diffs))


@dataclass(frozen=True)
class _Training:
    data: TrainingData
    model_file: Path


def _training(root: Path | None, diffs: list[Difference]) -> _Training | None:
    """The training states of the error model the calibration read (its manifest's first
    input); a difference where it cannot be read."""
    if root is None:
        return None
    m = read_manifest(root)
    inputs = [i for i in m.get("inputs", []) if isinstance(i, dict)]
    path = Path(str(inputs[0].get("path", ""))) if inputs else None
    if path is None or not path.exists():
        diffs.append(Difference(".", "error model", str(path), "missing: no scores recomputed"))
        return None
    try:
        model_file, fit_dir = resolve_model(path)
        return _Training(load_training(fit_dir, load_error_model(model_file), None), model_file)
    except InputError as exc:
        diffs.append(Difference(".", "error model", str(path), f"unreadable ({exc})"))
        return None


def _one(
    folder: Path, where: str, root: Path | None, training: _Training | None
) -> tuple[int, list[Difference]]:
    """One controller folder: ``(tick logs read, differences)``."""
    out: list[Difference] = []

    def diff(field: str, stored: Any, recomputed: Any) -> None:
        out.append(Difference(where, field, _shown(stored), _shown(recomputed)))

    try:
        d = load_controller_dir(folder)
    except InputError as exc:
        diff("certificate", "as loaded", f"refused: {exc}")
        return 0, out
    c = d.certificate.calibration
    if c is None:
        return 0, out  # a synth certificate: its numbers were recomputed on load, no flights
    if not c.evidence:
        diff("calibration.evidence", "none", "needed: recalibrate with this qsls version")
        return 0, out
    if training is not None:
        try:
            check_model_hash(load_controller_bound(folder), training.model_file, force=False)
        except InputError as exc:
            diff("error_model_sha256", d.certificate.error_model_sha256, str(exc))
    logs: dict[str, TickLog] = {}
    for e in c.evidence:
        path = Path(e.ticks)
        if not path.is_absolute():
            if root is None:
                diff(f"{e.flight} tick log", e.ticks, "missing (no calibration output around it)")
                continue
            path = root / path
        if not path.is_file():
            diff(f"{e.flight} tick log", e.ticks, "missing")
            continue
        sha = sha256_file(path)
        if sha != e.sha256:
            diff(f"{e.flight} tick log sha256", e.sha256[:12], sha[:12])
            continue
        try:
            logs[e.flight] = TickLog.read(path)
        except InputError as exc:
            diff(f"{e.flight} tick log", e.ticks, f"unreadable ({exc})")
            continue
        _conditions_of(d, e.flight, path, e.role, logs[e.flight], diff)
    _seeds(c, diff)
    _duration(d, logs, diff)
    if training is not None and all(e.flight in logs for e in c.evidence):
        _scores(d, logs, training.data, root, diff)
    if all(e.flight in logs for e in c.evidence if e.role == "calibration"):
        _monitor(d, logs, diff)
    return len(logs), out


def _monitor(d: ControllerDir, logs: dict[str, TickLog], diff: Any) -> None:
    """The innovation monitor's statistics from the calibration flights' logs under the
    certificate's sound monitor, and their quantile (docs/monitor.md#the-calibrated-mode; the
    record's rank and quantile against its own statistics are checked on load)."""
    c = d.certificate.calibration
    assert c is not None
    if c.monitor is None:
        return  # sound, none recorded (a record from before the calibrated mode)
    spec = sound_innovation_of(d)
    names = [e.flight for e in c.evidence if e.role == "calibration"]
    mine = [logs[n] for n in names]
    gate = d.certificate.gate
    want = monitor_calibration(
        spec, mine, hover_input(d), gate, c.monitor.mode, c.monitor.false_trip_rate
    )
    if len(want.statistics) != len(c.monitor.statistics):
        diff("calibration.monitor.statistics", len(c.monitor.statistics), len(want.statistics))
        return
    for i, (h, w) in enumerate(zip(c.monitor.statistics, want.statistics, strict=True)):
        if differs(h, w):
            diff(f"calibration.monitor.statistics[{i}]", h, w)
    if differs(c.monitor.quantile, want.quantile):
        diff("calibration.monitor.quantile", c.monitor.quantile, want.quantile)


def _conditions_of(
    d: ControllerDir, name: str, path: Path, role: str, log: TickLog, diff: Any
) -> None:
    """What a tick log says of its flight's conditions against the record: the perception
    condition (metadata kept under its hash) and the controller that flew it."""
    import pandas as pd  # deferred: only here, with the file already read once

    cert, c = d.certificate, d.certificate.calibration
    assert c is not None
    stated = c.conditions.get("perception")
    flown = pd.read_parquet(path).attrs.get(PERCEPTION_ATTR)
    if flown is not None and stated != flown:
        diff(f"conditions.perception ({name})", stated, flown)
    if (
        log.controller_sha256
        and role != "validation"
        and log.controller_sha256 != cert.controller_sha256
    ):
        diff(f"{name} flown by", cert.controller_sha256[:12], log.controller_sha256[:12])


def _seeds(c: Calibration, diff: Any) -> None:
    """The calibration flights' seeds are the record's (simulated flights)."""
    seeds = [e.seed for e in c.evidence if e.role == "calibration" and e.seed is not None]
    if seeds and seeds != list(c.seeds):
        diff("calibration.seeds", c.seeds, seeds)


def _duration(d: ControllerDir, logs: dict[str, TickLog], diff: Any) -> None:
    """The record's flight length against its flights': the longest calibration or range
    flight's ticks times the tick, to within one tick (the length a flight states)."""
    c = d.certificate.calibration
    assert c is not None
    dt = d.controller.dt
    names = {e.flight for e in c.evidence if e.role != "validation"}
    longest = max((len(lg.t) * dt for n, lg in logs.items() if n in names), default=None)
    if longest is not None and abs(longest - c.duration_s) >= dt * (1 - 1e-9):
        diff("calibration.duration_s", c.duration_s, longest)
    if not isinstance(c.conditions.get("duration_s"), int | float):
        return
    if abs(float(c.conditions["duration_s"]) - c.duration_s) > 1e-9 * c.duration_s:
        diff("conditions.duration_s", c.conditions["duration_s"], c.duration_s)


def _scores(
    d: ControllerDir, logs: dict[str, TickLog], training: TrainingData, root: Path | None, diff: Any
) -> None:
    """Every score, ``lambda_hat``, the rank, the tested range and the status by the
    calibration's own scoring and decision on the re-read logs."""
    cert = d.certificate
    c = cert.calibration
    assert c is not None
    nominal = _design_premise(d)
    if nominal is None:
        diff("calibration.nominal", c.nominal, "not a premise the scores can be recomputed under")
        return
    scores: list[float] = []
    ranged: list[float] = []
    reached: list[float] = []
    for e in (e for e in c.evidence if e.role != "validation"):
        parts = core.scored(logs[e.flight], nominal, training.distance, e.role)
        reached.append(float(parts["reached"]))
        (ranged if e.role == "range" else scores).append(float(parts["score"]))
    for what, have, want in (
        ("scores", c.scores, scores),
        ("range_scores", c.range_scores, ranged),
    ):
        if len(have) != len(want):
            diff(f"calibration.{what}", f"{len(have)} scores", f"{len(want)} flights")
            continue
        for i, (h, w) in enumerate(zip(have, want, strict=True)):
            if differs(h, w):
                diff(f"calibration.{what}[{i}]", h, w)
    flown = Scores(tuple(scores), tuple(ranged), tuple(reached), _crashed(root, d))
    got = core.decide(flown, nominal.numbers, core.responses(d), Rule.of_record(c))
    status, lam, rank, tested = got.status, got.lambda_hat, got.rank, got.tested_range
    decided: tuple[tuple[str, Any, Any], ...] = (
        ("calibration.lambda_hat", c.lambda_hat, lam),
        ("calibration.rank", c.rank, rank),
        ("calibration.tested_range", c.tested_range, tested),
        ("tested_range", cert.tested_range, tested),
        ("status", cert.status, status),
    )
    for field, stored, recomputed in decided:
        if differs(stored, recomputed):
            diff(field, stored, recomputed)


def _design_premise(d: ControllerDir) -> CertifiedPremise | None:
    """The premise the calibration scored under: the certificate's, with the design numbers
    its record states (:func:`qsls.pipeline.calibrate.core.nominal_numbers`) in place of the
    inflated ones (``a`` and ``rho*`` with them)."""
    cert = d.certificate
    c = cert.calibration
    assert c is not None
    premise = premise_of(d)
    numbers = core.nominal_numbers(cert)
    if premise is None or numbers is None:
        return None
    assert cert.norm_N_w is not None  # a calibrated certificate states it (checked on load)
    a = a_value(numbers.eps_w, cert.norm_N_w, numbers.delta, numbers.eps_b, cert.G_b or 0.0)
    rho_star = float(c.nominal["rho_star"] or 0.0)
    return dataclasses.replace(premise, numbers=numbers, a=a, rho_star=rho_star)


def _crashed(root: Path | None, d: ControllerDir) -> int:
    """Crashed calibration and range flights of this candidate (``scores.parquet``: a crash is
    the simulator's verdict, not in the tick log)."""
    import pandas as pd  # deferred: as above

    f = root / SCORES_FILE if root is not None else None
    if f is None or not f.is_file():
        return 0
    s = pd.read_parquet(f)
    if "crashed" not in s.columns:
        return 0
    c = d.certificate.calibration
    assert c is not None
    mine = s[s["flight"].isin([e.flight for e in c.evidence if e.role != "validation"])]
    return int(mine["crashed"].astype(bool).sum())


def check_paths(paths: Sequence[Path]) -> None:
    """Refuse a folder that does not exist, in one line."""
    for p in paths:
        if not Path(p).exists():
            raise InputError(f"verify: {p}: no such folder")


__all__ = ["VERIFIED", "Difference", "VerifyResult", "check_paths", "verify"]
