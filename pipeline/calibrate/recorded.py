"""Recorded flights as calibration, range and validation flights (docs/vehicle.md).

``qsls calibrate --recorded F ...`` takes the user's own flights in place of simulated ones:
each an ingest folder of a vehicle's log with its tick log (``qsls ingest LOG --mass M``
writes ``ticks.parquet``, :mod:`qsls.pipeline.ingest.ticks`). Before a flight counts for a
candidate it must be the candidate's own (:func:`qsls.pipeline.evaluate.flownby.flown_by`);
the flights must be distinct (no log twice, none a design flight by its log's hash or its
motion) and of one vehicle and one estimator. Then the scores, the quantile, the status rules
and the record are the simulated calibration's (:mod:`qsls.pipeline.calibrate.stage`), with
each flight's log hash in place of a seed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.core.artifacts import MANIFEST, read_manifest
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.ticks import TICKS_FILE, TickLog
from qsls.pipeline.errormodel.fit import same_motion
from qsls.pipeline.ingest.flight import FLIGHT_FILE

ROLES = ("calibration", "range", "validation")


@dataclass(frozen=True)
class RecordedFlight:
    """One recorded flight: its tick log and what its ingest recorded of it."""

    folder: Path
    role: str
    log: TickLog
    log_sha256: str
    """The vehicle's log file it was ingested from (its identity: a seed's place)."""
    mass: float
    conditions: dict[str, Any]
    stamps: dict[str, Any]
    """The controller identity the log carries (``qsls_controller_sha256``, ``qsls_gate``)."""
    label: str = ""
    """Its name in the tables where its folder's name is not unique among the flights."""

    @property
    def name(self) -> str:
        return self.label or self.folder.name


def load_recorded(folder: Path, role: str) -> RecordedFlight:
    """Read one recorded flight (an ingest folder with ``ticks.parquet``)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"recorded flight {folder}: no such folder; give an ingest folder")
    m = read_manifest(folder)
    if m.get("stage") != "ingest":
        raise InputError(
            f"recorded flight {folder}: written by '{m.get('stage')}', not 'qsls ingest': "
            "ingest the vehicle's log first (qsls ingest LOG --mass KG --out FOLDER)"
        )
    r = m.get("results") or {}
    facts = r.get("ticks")
    if not (folder / TICKS_FILE).is_file() or not isinstance(facts, dict):
        raise InputError(
            f"recorded flight {folder}: no tick log ({TICKS_FILE}); ingest the log again with "
            "--mass KG so the controller's commands are read back (docs/vehicle.md)"
        )
    try:
        log = TickLog.read(folder / TICKS_FILE)
    except (OSError, ValueError, KeyError) as exc:
        raise InputError(f"{folder / TICKS_FILE}: unreadable tick log ({exc})") from None
    sha = next((str(i.get("sha256", "")) for i in m.get("inputs", []) if isinstance(i, dict)), "")
    streams = r.get("streams") or {}
    conditions = {
        "source": "recorded",
        "estimator": str((streams.get("vio") or {}).get("topic", "")),
        "truth": str((streams.get("truth") or {}).get("topic", "")),
        "vehicle": {
            "mass": float(facts["mass_kg"]),
            "hover_thrust": facts.get("hover_thrust"),
            "hover_source": facts.get("hover_source"),
            "thr_mdl_fac": facts.get("thr_mdl_fac"),
        },
        "dt_s": float(facts["dt_s"]),
        "frame": str(facts.get("frame", "")),
        "reference": dict(facts.get("reference") or {}),
        # the flight's length as a simulated flight states it: its ticks times the tick
        "duration_s": len(log.t) * float(facts["dt_s"]),
    }
    return RecordedFlight(
        folder, role, log, sha, float(facts["mass_kg"]), conditions, dict(facts.get("stamps") or {})
    )


def expand(given: Sequence[Path]) -> list[Path]:
    """The flight folders ``given`` names: each an ingest folder, or a folder of them (its
    subfolders holding a manifest, by name)."""
    out: list[Path] = []
    for g in map(Path, given):
        if g.is_dir() and not (g / MANIFEST).is_file():
            inner = sorted(d for d in g.iterdir() if (d / MANIFEST).is_file())
            if not inner:
                raise InputError(
                    f"recorded flights {g}: neither an ingest folder nor a folder of them"
                )
            out += inner
        else:
            out.append(g)
    return out


def load_all(by_role: Mapping[str, Sequence[Path]]) -> list[RecordedFlight]:
    """Every recorded flight, refused in one line where two are one flight, or where they are
    not of one vehicle and one estimator (docs/vehicle.md#what-voids-it)."""
    flights = [load_recorded(f, role) for role in ROLES for f in expand(by_role.get(role, ()))]
    seen: dict[str, RecordedFlight] = {}
    for f in flights:
        key = f.log_sha256 or str(f.folder.resolve())
        if key in seen:
            raise InputError(
                f"recorded flights {seen[key].folder} ({seen[key].role}) and {f.folder} "
                f"({f.role}) come from one log: a flight counts once; pass it once"
            )
        seen[key] = f
    first = flights[0] if flights else None
    for f in flights[1:]:
        assert first is not None
        for what, a, b in (
            ("vehicle mass", first.mass, f.mass),
            *(
                (what, first.conditions[k], f.conditions[k])
                for what, k in (("estimator", "estimator"), ("tick", "dt_s"), ("frame", "frame"))
            ),
        ):
            if not (np.isclose(a, b, rtol=1e-3) if isinstance(a, float) else a == b):
                raise InputError(
                    f"recorded flight {f.folder}: {what} {b} while {first.folder} has {a}: "
                    "a certificate is calibrated on flights of one vehicle and one estimator; "
                    "calibrate each separately"
                )
    names = [f.folder.name for f in flights]  # two folders of one name: their parent tells
    return [
        dataclasses.replace(f, label=f"{f.folder.parent.name}/{f.folder.name}")
        if names.count(f.folder.name) > 1
        else f
        for f in flights
    ]


def design_logs(fit_dir: Path) -> set[str]:
    """The sha256 of the vehicle logs behind the fit in ``fit_dir`` (its ingest folders'
    inputs): a calibration flight among them is a design flight."""
    out: set[str] = set()
    try:
        fit = read_manifest(fit_dir)
    except InputError:
        return out
    for i in fit.get("inputs", []):
        p = Path(str(i.get("path", ""))) if isinstance(i, dict) else None
        if p is None:
            continue
        folder = p if p.is_dir() else p.parent
        try:
            m = read_manifest(folder)
        except InputError:
            continue
        out |= {str(j.get("sha256")) for j in m.get("inputs", []) if isinstance(j, dict)}
    out.discard("None")
    return out


def refuse_design(flights: Sequence[RecordedFlight], fit_dir: Path) -> None:
    """A design flight is no calibration flight: refused by its log's hash, and by its motion
    (the same truth at the same times as a training flight: another ingest of one flight)."""
    design = design_logs(fit_dir)
    for f in flights:
        if f.log_sha256 and f.log_sha256 in design:
            raise InputError(
                f"recorded flight {f.folder} ({f.role}) is a design flight: its log was "
                f"ingested for the fit in {fit_dir}; a certificate is calibrated and "
                "validated on flights its design never saw"
            )
    try:
        given = [
            Path(str(i.get("path", "")))
            for i in read_manifest(fit_dir).get("inputs", [])
            if isinstance(i, dict)
        ]
    except InputError:
        return
    train = [(p / FLIGHT_FILE if p.is_dir() else p) for p in given]
    frames = {p: pd.read_parquet(p) for p in train if p.name == FLIGHT_FILE and p.is_file()}
    for f in flights:
        mine = f.folder / FLIGHT_FILE
        if not mine.is_file():
            continue
        a = pd.read_parquet(mine)
        for p, b in frames.items():
            if same_motion(a, b):
                raise InputError(
                    f"recorded flight {f.folder} ({f.role}) is the design flight {p.parent}: "
                    "the same motion at the same times; a flight counts once"
                )
