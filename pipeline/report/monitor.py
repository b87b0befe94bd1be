"""The report's section on the onboard premise monitor (docs/monitor.md): its catch share on
the flown flights (:func:`qsls.pipeline.fly.assured.catch_share` on the fly stage's
``assumptions.parquet``) and, when the fly stage flew runtime-assured controllers
(``assured: true``), how they flew against the controller alone and PD alone
(:func:`qsls.pipeline.fly.assured.assured_comparison` on ``assured.parquet`` and
``flights.parquet``; per estimator, on the stage's flights of every estimator, when it flew
several)."""

from __future__ import annotations

import math
from typing import Any

from qsls.pipeline.evaluate.verdict import ASSUMPTIONS_FILE
from qsls.pipeline.fly.assured import (
    ASSURED,
    ASSURED_FILE,
    ESTIMATOR,
    assured_comparison,
    catch_share,
)
from qsls.pipeline.fly.estimators import FLIGHTS_FILE
from qsls.pipeline.fly.tables import FLOWN_FILE
from qsls.pipeline.report.document import Section
from qsls.pipeline.report.facts import Facts, g4, pct


def _share(v: Any) -> str:
    return "-" if v != v else pct(v)  # NaN: no broken flight, no share


def _calibration_notes(assured: Any) -> list[str]:
    """A calibrated certificate flown in another perception condition than its calibration's
    promises nothing there (docs/calibration.md): one note per such controller."""
    if "calibrated_perception" not in assured:
        return []
    notes = []
    for name, g in assured.groupby("controller", sort=False):
        cal = str(g["calibrated_perception"].iloc[0])
        other = sorted({str(c) for c in g["condition"]} - {cal})
        if cal and other:
            notes.append(
                f"{name} was calibrated in {cal} perception: its certificate promises nothing "
                f"about the flights in {', '.join(other)} perception (its monitor is still sound "
                "for its premise)"
            )
    return notes


MAX_TRIP_ROWS = 20
"""The trips table lists at most this many flights (the catch share counts them all)."""


def _trips_table(sec: Section, assumptions: Any) -> None:
    """A trip explains itself (docs/monitor.md, The bits): per flight on which the monitor
    tripped, the first failing assumption and its time, the trip's time and delay, and which
    test on which channel tripped for how long (``monitor_summary``)."""
    if "monitor_summary" not in assumptions:
        return
    tripped = assumptions[assumptions["monitor_trips"].to_numpy(int) > 0]
    if not len(tripped):
        return
    rows = []
    for r in tripped.head(MAX_TRIP_ROWS).to_dict(orient="records"):
        failed = str(r.get("first_failed", "") or "")
        t_fail = r.get(f"{failed}_t", math.nan) if failed else math.nan
        delay = r["monitor_t"] - t_fail if t_fail == t_fail else math.nan
        rows.append([
            r["flight"], r["controller"], r["condition"],
            f"{failed} at {g4(t_fail)} s" if failed and t_fail == t_fail else (failed or "none"),
            g4(r["monitor_t"]), g4(delay), str(r["monitor_summary"]),
        ])  # fmt: skip
    more = len(tripped) - len(rows)
    sec.table(
        ["flight", "controller", "condition", "first failing assumption", "trip (s)",
         "delay (s)", "what tripped, for how long"],
        rows,
        "Each trip in words: the test and channel that tripped, the seconds its bit was set "
        "and from when (the first failing assumption from the post-flight checks)",
        notes=[f"{more} more flights tripped ({ASSUMPTIONS_FILE})"] if more > 0 else [],
        text_cols=[0, 1, 2], wrap_cols=[3], wide_cols=[6],
    )  # fmt: skip


def _calibrated_note(sec: Section, f: Facts) -> None:
    """Name the controllers whose innovation monitor is calibrated: their window-sum trips are
    alarms at a stated rate, not proofs (docs/monitor.md#the-calibrated-mode)."""
    calibrated = sorted(
        c.name for c in f.controllers
        if ((c.cert.get("calibration") or {}).get("monitor") or {}).get("mode") == "calibrated"
    )  # fmt: skip
    if calibrated:
        sec.text(
            f"{', '.join(calibrated)} fly the innovation monitor's calibrated mode "
            "(docs/monitor.md#the-calibrated-mode): their window sums trip at a conformal "
            "quantile of the calibration flights' statistics, so such a trip is an alarm with a "
            "stated false-trip probability per flight, not a proof, and a trip on a flight whose "
            "checks all held counts against that rate."
        )


def section_monitor(f: Facts, counter: list[int]) -> Section | None:
    import pandas as pd

    if not f.fly_folder:
        return None
    fly = f.run_dir / f.fly_folder
    a_path, s_path = fly / ASSUMPTIONS_FILE, fly / ASSURED_FILE
    assumptions = pd.read_parquet(a_path) if a_path.is_file() else pd.DataFrame()
    assured = pd.read_parquet(s_path) if s_path.is_file() else pd.DataFrame()
    if not len(assumptions) and not len(assured):
        return None
    sec = Section("Onboard monitor and runtime assurance", id="monitor")
    sec.text(
        "The onboard monitor (docs/monitor.md) reads only what the controller reads, y - r, and "
        "trips when that measurement proves the certificate's premise broken on this flight. It "
        "is sound (it never trips while the premise holds) and one-sided: most broken premises "
        "do not show in the measurement. In runtime-assured mode the certified controller flies "
        "until its monitor trips, then the PD reference flies (or holds) from that tick on.",
        lead=True,
    )
    _calibrated_note(sec, f)
    if len(assumptions):
        c = catch_share(assumptions)
        sec.table(
            ["scope", "controllers' own flights", "premise broken", "monitor tripped",
             "catch share", "trips with every check held", "mean delay (s)"],
            [[r.scope, r.flights, r.broken, r.caught, _share(r.catch_share),
              r.trips_premise_held, g4(r.mean_delay_s)] for r in c.itertuples()],
            "Catch share: of the flights on which the post-flight checks found a broken "
            "assumption, the share on which the monitor tripped (delay: trip time minus the "
            "first failing assumption's)",
            text_cols=[0, 4],
        )  # fmt: skip
        _trips_table(sec, assumptions)
    if len(assured):
        keyed = ESTIMATOR in assured  # several estimators: each meets its own flights
        flights = pd.read_parquet(fly / (FLIGHTS_FILE if keyed else FLOWN_FILE))
        comp = assured_comparison(flights, assured)
        status = dict(zip(assured["controller"], assured["status"], strict=False))
        fallback = str(assured["fallback"].iloc[0])
        rows = []
        for r in comp.itertuples():
            switched = "-"
            if r.flown == ASSURED:
                switched = f"{r.switched:.0f} of {r.flights} ({pct(r.switching_rate)})"
                if r.switched:
                    switched += f", mean trip {g4(r.mean_trip_s)} s"
                if "envelope_peak" in assured:
                    mine = assured[(assured["condition"] == r.condition)
                                   & (assured["controller"] == r.controller)]  # fmt: skip
                    if keyed:
                        mine = mine[mine[ESTIMATOR] == r.estimator]
                    switched += f"; peak {g4(mine['envelope_peak'].max())} of a threshold"
            rows.append([
                f"{r.condition} ({r.estimator})" if keyed else r.condition,
                f"{r.controller} ({status.get(r.controller, '')})", r.flown,
                r.flights, r.crashed, g4(r.tracking_rms_m), g4(r.tracking_max_m), switched,
            ])  # fmt: skip
        sec.table(
            ["condition", "controller (status)", "flown", "flights", "crashed",
             "tracking RMS (m)", "tracking max (m)", "handed over"],
            rows,
            f"Runtime-assured flights (fallback: {fallback}) against the controller alone and "
            "PD alone on the same seeds"
            + (", per estimator (in brackets after the condition)" if keyed else "")
            + " (tracking: mean of the RMS, max of the max; handed "
            "over: the flights whose monitor tripped, their mean trip time, and the largest "
            "|y_i - r_i| / threshold_i on the envelope channels: above 1 trips)",
            notes=[
                *(f"{n} is {st}, not certified: it flew with the monitor of its {st} premise, "
                  "and no guarantee is claimed for it"
                  for n, st in status.items() if st != "certified"),
                *_calibration_notes(assured),
            ],
            text_cols=[0, 1, 2, 7],
        )  # fmt: skip
    return sec
