"""The runtime-assured flights and the onboard monitor's catch share (docs/monitor.md, The
fallback; docs/evaluation.md, Runtime-assured flights).

- :func:`assured_comparison`: per condition and monitored controller (and per estimator,
  when the tables carry an ``estimator`` column: a fly stage with several), the controller
  alone, runtime-assured (:class:`qsls.pipeline.sim.assured.AssuredController`) and PD alone
  on the same seeds: flights, crashes, tracking RMS (mean) and max, and for the assured
  flights the switching rate (the share of flights whose monitor tripped, so the fallback
  flew) and the mean trip time over the flights that tripped.
- :func:`catch_share`: of the flights on which the post-flight checks found a broken premise
  (any of the five assumptions of :mod:`qsls.pipeline.evaluate.assumptions` failed), the
  share whose monitor tripped; beside it the trips on flights whose checks all held (zero if
  the monitor is sound and the checks cover its premise) and the mean delay from the first
  failing assumption to the trip; over all flights, per condition and, with an ``estimator``
  column, per estimator and condition.

Arrays and tables in, tables out; nothing is flown or written here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.control.monitor import first_test, trip_summary
from qsls.pipeline.evaluate.assumptions import ASSUMPTIONS

ASSURED_FILE = "assured.parquet"
ASSURED_SUFFIX = "_assured"
"""An assured flight's controller name: the monitored controller's, then this."""

ALONE, ASSURED, PD_ALONE = "alone", "assured", "PD alone"
ESTIMATOR = "estimator"
"""The column that keys a fly stage's rows by estimator when it flew several."""


def trip_columns(flew: Sequence[str], bits: Sequence[int], t: np.ndarray) -> dict[str, Any]:
    """One assured flight's handover from its per-tick record: whether the monitor tripped,
    the trip tick and time, which test tripped first
    (:func:`qsls.pipeline.control.monitor.first_test`), every test's trips in words
    (:func:`qsls.pipeline.control.monitor.trip_summary`), the share of ticks the fallback
    flew."""
    b = np.asarray(bits, dtype=int)
    hit = np.flatnonzero(b)
    first = int(hit[0]) if len(hit) else None
    fallback = 0 if first is None else len(flew) - first
    return {
        "tripped": first is not None,
        "trip_tick": -1 if first is None else first,
        "trip_t": math.nan if first is None else float(t[first]),
        "trip_first": "" if first is None else first_test(int(b[first])),
        "trip_summary": "; ".join(trip_summary(b, float(t[1] - t[0]) if len(t) > 1 else 0.0, t)),
        "fallback_share": fallback / len(flew) if len(flew) else 0.0,
    }


def assured_comparison(
    flights: pd.DataFrame, assured: pd.DataFrame, pd_name: str = "pd"
) -> pd.DataFrame:
    """Per condition and monitored controller (``assured``'s ``controller``, the base name),
    three rows on the seeds the assured controller flew: the controller ``alone``
    (``flights``), ``assured``, and ``PD alone`` (``flights``' ``pd_name``, if flown). When
    both tables have an ``estimator`` column, per estimator too (first column), each assured
    flight against the flights of its own estimator."""
    rows: list[dict[str, Any]] = []
    if not len(assured):
        return pd.DataFrame(rows)
    keyed = ESTIMATOR in assured and ESTIMATOR in flights
    keys = [ESTIMATOR, "condition", "controller"] if keyed else ["condition", "controller"]
    for key, a in assured.groupby(keys, sort=False):
        *vio, cond, name = key
        seeds = set(a["seed"])
        same = flights[(flights["condition"] == cond) & flights["seed"].isin(seeds)]
        if keyed:
            same = same[same[ESTIMATOR] == vio[0]]
        for flown, df in ((ALONE, same[same["controller"] == name]), (ASSURED, a),
                          (PD_ALONE, same[same["controller"] == pd_name])):  # fmt: skip
            if not len(df):
                continue
            row: dict[str, Any] = {
                **({ESTIMATOR: vio[0]} if keyed else {}),
                "condition": cond, "controller": name, "flown": flown, "flights": len(df),
                "crashed": int(df["crashed"].sum()),
                "tracking_rms_m": float(df["tracking_rms_m"].mean()),
                "tracking_max_m": float(df["tracking_max_m"].max()),
                "perception_error_rms": float(df["perception_error_rms"].mean()),
                "switched": math.nan, "switching_rate": math.nan, "mean_trip_s": math.nan,
            }  # fmt: skip
            if flown == ASSURED:
                tripped = df[df["tripped"].astype(bool)]
                row["switched"] = len(tripped)
                row["switching_rate"] = len(tripped) / len(df)
                row["mean_trip_s"] = float(tripped["trip_t"].mean()) if len(tripped) else math.nan
            rows.append(row)
    return pd.DataFrame(rows)


def premise_broken(assumptions: pd.DataFrame) -> pd.Series:
    """Per row of an assumption table: did any of the five assumptions fail (a crash alone
    does not count: it breaks no premise)."""
    held = np.ones(len(assumptions), dtype=bool)
    for name in ASSUMPTIONS:
        held &= assumptions[f"{name}_holds"].to_numpy(bool)
    return pd.Series(~held, index=assumptions.index)


def catch_share(assumptions: pd.DataFrame) -> pd.DataFrame:
    """The monitor's catch share on the flights of an assumption table (``assumptions.parquet``:
    each certified or relaxed robust controller's own flights, with ``monitor_trips`` and
    ``monitor_t``): one row for all flights, then one per condition. ``catch_share`` is
    ``caught / broken`` (NaN without a broken flight); ``trips_premise_held`` counts trips on
    flights whose every assumption held; ``mean_delay_s`` is the mean over caught flights of
    the trip time minus the earliest failing assumption's time. With an ``estimator`` column
    (several estimators' flights), one row per estimator (``camera: all``) and per estimator
    and condition (``camera: degraded``) follow."""
    cols = ["scope", "flights", "broken", "caught", "catch_share", "trips_premise_held",
            "mean_delay_s"]  # fmt: skip
    if not len(assumptions):
        return pd.DataFrame(columns=cols)
    a = assumptions.assign(_broken=premise_broken(assumptions),
                           _tripped=assumptions["monitor_trips"].to_numpy(int) > 0)  # fmt: skip
    fail_t = np.column_stack([a[f"{n}_t"].to_numpy(float) for n in ASSUMPTIONS])
    first_fail = np.where(np.isnan(fail_t), np.inf, fail_t).min(axis=1)
    a = a.assign(_delay=a["monitor_t"].to_numpy(float) - first_fail)
    groups: list[tuple[str, pd.DataFrame]] = [("all", a)]
    if "condition" in a:
        groups += [(str(c), g) for c, g in a.groupby("condition", sort=False)]
    if ESTIMATOR in a:
        for vio, ga in a.groupby(ESTIMATOR, sort=False):
            groups.append((f"{vio}: all", ga))
            if "condition" in ga:
                groups += [(f"{vio}: {c}", g) for c, g in ga.groupby("condition", sort=False)]
    rows = []
    for scope, g in groups:
        broken = int(g["_broken"].sum())
        caught = g[g["_broken"] & g["_tripped"]]
        rows.append({
            "scope": scope, "flights": len(g), "broken": broken, "caught": len(caught),
            "catch_share": len(caught) / broken if broken else math.nan,
            "trips_premise_held": int((~g["_broken"] & g["_tripped"]).sum()),
            "mean_delay_s": float(caught["_delay"].mean()) if len(caught) else math.nan,
        })  # fmt: skip
    return pd.DataFrame(rows, columns=cols)
