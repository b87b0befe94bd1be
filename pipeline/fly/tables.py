"""The fly stage's tables, from flown flights (:class:`qsls.pipeline.fly.flights.FlyOutcome`)
and the certificates already read: nothing is flown or read here (docs/evaluation.md, Flying
the controllers).

- :func:`flight_table` (``flights.parquet``): one row per flight, its metrics;
  :func:`per_controller_table` (``per_controller.parquet``): per controller and condition, the
  mean over seeds (max for the maxima, the sum of crashes), with the controller's own bound
  check beside it (:func:`bound_columns`);
- :func:`assumption_table` (``assumptions.parquet``): every assumption of the guarantee on each
  certified (or relaxed) robust controller's own flights, and what its onboard monitor would
  have said (:func:`monitor_columns`);
- :func:`assured_table` (``assured.parquet``): the runtime-assured flights and their handover.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.control.artifacts import ControllerDir
from qsls.pipeline.control.innovation import NO_INNOVATION
from qsls.pipeline.control.monitor import (
    envelope_peak,
    first_test,
    innovation_of,
    monitor_of,
    onboard_flags,
    trip_summary,
)
from qsls.pipeline.evaluate.assumptions import FlownLog, check_assumptions, crashed
from qsls.pipeline.evaluate.certified import (
    ControllerBound,
    certificate_for,
    outside_calibration,
    premise_of,
)
from qsls.pipeline.fly.assured import ASSURED_SUFFIX, ESTIMATOR, trip_columns
from qsls.pipeline.fly.flights import FlyOutcome
from qsls.pipeline.sim.options import SimOptions

FLOWN_FILE = "flights.parquet"
"""One row per flight flown (the primary estimator's)."""
PER_CONTROLLER_TABLE = "per_controller.parquet"
"""Per controller and condition, means over seeds (the primary estimator's)."""

CIRCLE_COLUMNS = (
    "tracking_rms_m_circle",
    "tracking_max_m_circle",
    "perception_error_rms_circle",
    "perception_error_max_circle",
    "reaction_vs_pd_circle",
)
"""The metrics over the circle with the paper's 1 s smoothing
(:func:`qsls.pipeline.fly.paper.circle_metrics`)."""


def premise_rows(bounds: Sequence[ControllerBound]) -> list[dict[str, Any]]:
    """Each controller's premise for the paper's strict bound (``R0``, ``S``, ``||Phi_xe||``,
    ``||Phi_ue||``; :func:`qsls.pipeline.fly.paired.strict_bounds`)."""
    return [
        {"name": b.name, "status": b.status, "R0": b.r0, "S": b.numbers.S,
         "norm_phi_xe": b.norm_phi_xy, "norm_phi_ue": b.certificate.get("norm_phi_uy")}
        for b in bounds
        if math.isfinite(b.numbers.S) and math.isfinite(b.norm_phi_xy) and math.isfinite(b.r0)
    ]  # fmt: skip


def gain_norms(bounds: Sequence[ControllerBound]) -> dict[str, dict[str, float]]:
    """``{controller: {phi_xe, phi_ue}}``: the gains from perception error to state and to
    input of each controller's taps."""
    out = {}
    for b in bounds:
        ue = b.certificate.get("norm_phi_uy")
        out[b.name] = {
            "phi_xe": float(b.norm_phi_xy),
            "phi_ue": float(ue) if ue is not None else math.nan,
        }
    return out


def flight_table(outcomes: Sequence[FlyOutcome]) -> pd.DataFrame:
    rows = []
    for o in outcomes:
        m = o.metrics
        rows.append(
            {
                "flight": o.name,
                "controller": o.controller,
                "condition": o.condition,
                "seed": o.seed,
                "duration_s": m["duration_s"],
                "tracking_rms_m": m["tracking_rms_m"],
                "tracking_max_m": m["tracking_max_m"],
                "perception_error_rms": m["perception_error_rms"],
                "perception_error_max": m["perception_error_max"],
                "control_effort_rms": m["control_effort_rms"],
                "control_smoothness_rms": m["control_smoothness_rms"],
                "attitude_smoothness": m["attitude_smoothness"],
                "smoothness_vs_pd": m["smoothness_vs_pd"],
                "reaction_vs_pd": m["reaction_vs_pd"],
                "error_reaction_vs_pd": m["error_reaction_vs_pd"],
                "attitude_diff_from_pd_rms": m["attitude_diff_from_pd_rms"],
                "angular_rate_rms": m["angular_rate_rms"],
                "blur_px_mean": m["blur_px_mean"],
                "features_per_frame": m.get("features_per_frame", math.nan),
                **{k: m.get(k, math.nan) for k in CIRCLE_COLUMNS},
                "crashed": bool(m["crashed"]),
                "crash_reason": m["crash_reason"] or "",
                "ingest_error": o.ingest_error or "",
            }
        )
    return pd.DataFrame(rows)


def per_controller_table(flights: pd.DataFrame) -> pd.DataFrame:
    """Mean over seeds per controller and condition (max for the maxima, sum of crashes)."""
    agg = {
        "tracking_rms_m": "mean",
        "tracking_max_m": "max",
        "perception_error_rms": "mean",
        "perception_error_max": "max",
        "control_effort_rms": "mean",
        "control_smoothness_rms": "mean",
        "smoothness_vs_pd": "mean",
        "reaction_vs_pd": "mean",
        "error_reaction_vs_pd": "mean",
        "attitude_diff_from_pd_rms": "mean",
        "angular_rate_rms": "mean",
        "blur_px_mean": "mean",
        "features_per_frame": "mean",
        **{k: ("max" if "_max_" in k else "mean") for k in CIRCLE_COLUMNS},
        "crashed": "sum",
        "seed": "count",
    }
    agg = {k: v for k, v in agg.items() if k in flights}
    g = flights.groupby(["condition", "controller"], sort=False).agg(agg).reset_index()
    return g.rename(columns={"seed": "flights"})


def bound_columns(per: pd.DataFrame, checks: pd.DataFrame) -> pd.DataFrame:
    """Add each controller's own bound check (if it has a certificate) to ``per``."""
    if checks.empty:
        return per
    own = checks[checks["controller"] == checks["flown_by"]]
    g = (
        own.groupby(["condition", "controller"], sort=False)
        .agg(
            gamma_strict=("gamma_strict", "first"),
            gamma_max=("gamma", "max"),
            frac_under_gamma=("frac_under_gamma", "mean"),
            frac_under_gamma_strict=("frac_under_gamma_strict", "mean"),
            max_ratio=("max_ratio", "max"),
            gamma_nominal_max=("gamma_nominal", "max"),
            max_nominal_ratio=("nominal_ratio", "max"),
            bound_holds_all=("bound_holds", lambda b: bool(b.astype(bool).all())),
        )
        .reset_index()
    )
    return per.merge(g, on=["condition", "controller"], how="left")


def monitor_columns(
    spec: Any, log: Any, gate: float | None, innovation: Any = NO_INNOVATION,
    u_hover: Any = None,
) -> dict[str, Any]:  # fmt: skip
    """What the onboard premise monitor (docs/monitor.md) would have said on a flown log, the
    envelope and the innovation monitor both
    (:func:`qsls.pipeline.control.monitor.onboard_flags` on ``y - r`` and the deviation command
    ``u - u_hover - uff`` flown, at the controller's ticks, from the reset at take-off): the
    ticks it trips on, the first one's time, the test that tripped first (``envelope``,
    ``outlier count``, ``innovation outlier count``, ``disturbance on vz``) and every test's
    trips in words (:func:`qsls.pipeline.control.monitor.trip_summary`)."""
    du = np.asarray(log.u, float) - np.asarray(log.uff, float)
    du = du - (np.zeros(3) if u_hover is None else np.asarray(u_hover, float))
    t = np.asarray(log.t, float)
    flags = onboard_flags(spec, innovation, np.asarray(log.y) - np.asarray(log.ref), du, gate)
    hit = np.flatnonzero(flags)
    first = int(hit[0]) if len(hit) else None
    dt = float(t[1] - t[0]) if len(t) > 1 else 0.0
    return {
        "monitor_trips": len(hit),
        "monitor_t": float(t[first]) if first is not None else float("nan"),
        "monitor_first": "" if first is None else first_test(int(flags[first])),
        "monitor_summary": "; ".join(trip_summary(flags, dt, t)),
    }


def assumption_table(
    outcomes: Sequence[FlyOutcome],
    bounds: Sequence[ControllerBound],
    training: Any,
    dirs: Mapping[Path, ControllerDir],
    by_condition: Mapping[tuple[str, str], ControllerBound] | None = None,
) -> pd.DataFrame:
    """:func:`qsls.pipeline.evaluate.assumptions.check_assumptions` on every flight a certified
    (or relaxed) robust controller flew, from its own log at its own ticks, against the
    certificate of its condition (:func:`certificate_for`; ``dirs``: each certificate's folder
    as read)."""
    named = {b.name: b for b in bounds}
    read: dict[Path, tuple[Any, Any, Any, Any]] = {}

    def watched(b: ControllerBound) -> tuple[Any, Any, Any, Any]:
        """(premise, monitor, innovation monitor, calibration) of one certificate, once."""
        if b.folder not in read:
            d = dirs[b.folder]
            c = premise_of(d)
            read[b.folder] = (
                (c, monitor_of(d), innovation_of(d), d.certificate.calibration)
                if c is not None
                else (None, None, NO_INNOVATION, None)
            )
        return read[b.folder]

    rows = []
    for o in outcomes:
        b = certificate_for(o.controller, o.condition, named, by_condition)
        if b is None:
            continue
        c, monitor, innovation, cal = watched(b)
        if c is None or len(o.t_ctrl) < 2:
            continue  # a crashed flight is checked on the ticks it flew: a crash is no excuse
        log = FlownLog(o.t_ctrl, o.x_ctrl, o.y_ctrl, o.u_ctrl, o.ref_ctrl, o.uff_ctrl)
        row = check_assumptions(log, c, training.distance)
        row.update(monitor_columns(monitor, log, c.numbers.gate, innovation, c.u_hover))
        if o.metrics.get("crashed"):
            row = crashed(row, o.extra.get("crash_time_s"), o.metrics.get("crash_reason"))
        row["outside_calibration"] = outside_calibration(
            cal, o.condition, float(o.metrics.get("duration_s", o.t_ctrl[-1])), o.estimator,
            o.extra.get("conditions"),
        )  # fmt: skip
        rows.append({"flight": o.name, "controller": o.controller, "status": b.status,
                     "crashed": bool(o.metrics.get("crashed")),
                     "condition": o.condition, "seed": o.seed, **row})  # fmt: skip
    return pd.DataFrame(rows)


def assured_table(
    outcomes: Sequence[FlyOutcome], status: dict[str, str], fallback: str,
    folders: dict[str, Path], dirs: Mapping[Path, ControllerDir], *, by_estimator: bool = False,
    by_condition: Mapping[tuple[str, str], ControllerBound] | None = None,
) -> pd.DataFrame:  # fmt: skip
    """One row per runtime-assured flight: its flight-table columns (``controller`` the
    monitored controller's name), the certificate's status and the perception its calibration
    flew in (``calibrated_perception``, empty if not calibrated), the fallback, the handover
    (:func:`qsls.pipeline.fly.assured.trip_columns`) and ``envelope_peak``, the largest
    ``|y_i - r_i| / threshold_i`` over the flight's ticks and envelope channels
    (:func:`qsls.pipeline.control.monitor.envelope_peak`: how close it came to a trip).
    ``by_estimator`` (a stage with several estimators) puts the flight's estimator first.
    A flight's certificate is its condition's where ``by_condition`` holds one (the one its
    monitor watched: :func:`qsls.pipeline.fly.flights.make_jobs`); ``dirs``: each certificate's
    folder as read."""
    if not outcomes:
        return pd.DataFrame()
    table = flight_table(outcomes)
    base = [o.controller.removesuffix(ASSURED_SUFFIX) for o in outcomes]
    by_condition = by_condition or {}

    def folder(b: str, cond: str) -> Path:
        own = by_condition.get((cond, b))
        return own.folder if own is not None else folders[b]

    where = [folder(b, o.condition) for o, b in zip(outcomes, base, strict=True)]
    cdirs = {f: dirs[f] for f in dict.fromkeys(where)}
    spec = {f: monitor_of(c) for f, c in cdirs.items()}
    trips = pd.DataFrame([
        {**trip_columns(o.extra["flew"], o.extra["bits"], o.t_ctrl),
         "envelope_peak": envelope_peak(spec[f], o.y_ctrl - o.ref_ctrl, cdirs[f].certificate.gate)}
        for o, f in zip(outcomes, where, strict=True)
    ])  # fmt: skip
    table["controller"] = base
    table.insert(2, "status", [
        own.status if (own := by_condition.get((o.condition, b))) is not None else status.get(b, "")
        for o, b in zip(outcomes, base, strict=True)
    ])  # fmt: skip
    # a calibrated certificate speaks for flights of its calibration's perception only
    perception = {
        f: str(cal.conditions.get("perception", "")) if (cal := c.certificate.calibration) else ""
        for f, c in cdirs.items()
    }
    table.insert(3, "calibrated_perception", [perception[f] for f in where])
    table.insert(4, "fallback", fallback)
    if by_estimator:
        table.insert(0, ESTIMATOR, [o.estimator for o in outcomes])
    return pd.concat([table, trips], axis=1)


def motion_parts(sim: SimOptions) -> list[str]:
    """The VIO emulator's motion-dependent parts switched on for the flights."""
    return [k for k in ("blur", "motion_drift", "feature_loss") if getattr(sim.vio, k, False)]


def true_lipschitz(outcomes: Sequence[FlyOutcome]) -> dict[str, float]:
    """The emulator's Lipschitz constant per condition (the largest over flights); none for
    the camera loop's flights (no designed bias field, so no true constant to compare)."""
    true_l: dict[str, float] = {}
    for o in outcomes:
        if o.extra["lipschitz"] is None:
            continue
        true_l[o.condition] = max(true_l.get(o.condition, 0.0), float(o.extra["lipschitz"]))
    return true_l
