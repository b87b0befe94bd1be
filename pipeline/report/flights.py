"""The flights behind the run: what was ingested (and simulated), drawn by the report.

One row per flight in a narrow table; every simulator result as a CSV beside the report.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core import style
from qsls.pipeline.core.artifacts import figure_bytes, read_manifest
from qsls.pipeline.ingest.flight import errors, measurements, read_flight, states
from qsls.pipeline.report.document import Figure, Section, figure_of, stage_pngs
from qsls.pipeline.report.facts import Facts


def _drawn(counter: list[int], stem: str, fig: Any, caption: str) -> Figure:
    import matplotlib.pyplot as plt

    counter[0] += 1
    try:
        return Figure(f"fig{counter[0]:02d}_{stem}.png", figure_bytes(fig, "png", 110), caption)
    finally:
        plt.close(fig)


def _flight_figures(data: list[tuple[str, Any]], counter: list[int]) -> list[Figure]:
    """Top view of truth and VIO per flight, and ||e|| over time per flight."""
    fig_xy, ax = style.subplots(width=style.HALF_WIDTH_IN, height=6.0)
    fig_e, ax_e = style.subplots(width=style.WIDTH_IN, height=3.6)
    for i, (name, df) in enumerate(data):
        col = style.CYCLE[i % len(style.CYCLE)]
        x, y, e = states(df), measurements(df), errors(df)
        ax[0, 0].plot(x[:, 0], x[:, 1], color=col, lw=1.2, label=f"{name} truth")
        ax[0, 0].plot(y[:, 0], y[:, 1], color=col, lw=0.8, ls="--", label=f"{name} VIO")
        ax_e[0, 0].plot(df["t"].to_numpy(), np.abs(e).max(axis=1), color=col, lw=0.9, label=name)
    a = ax[0, 0]
    a.set_xlabel("x (m)")
    a.set_ylabel("y (m)")
    a.set_aspect("equal", adjustable="datalim")
    a.set_title("Truth (solid) and VIO (dashed)", loc="left")
    style.legend_below(fig_xy, ncol=2)
    b = ax_e[0, 0]
    b.set_xlabel("t (s)")
    b.set_ylabel("||e||_inf")
    b.set_title("Perception error over time", loc="left")
    style.legend_right(b)
    return [
        _drawn(counter, "flights_xy", fig_xy, "Trajectories of every ingested flight"),
        _drawn(counter, "flights_error", fig_e, "Perception error ||e_k|| (inf norm) per flight"),
    ]


def section_flights(f: Facts, counter: list[int]) -> Section | None:
    folders: list[Path] = f.stages.get("ingest", [])
    if not folders:
        return None
    sec = Section("Flights", id="flights")
    rows, data = [], []
    for folder in folders:
        name = folder.name
        res = read_manifest(folder).get("results", {})
        df = read_flight(folder)
        e = errors(df)
        data.append((name, df))
        rows.append(
            [
                name,
                len(df),
                float(df["t"].iloc[-1] - df["t"].iloc[0]) if len(df) else float("nan"),
                res.get("time_offset_s", float("nan")),
                (res.get("alignment") or {}).get("yaw_rad", float("nan")),
                float(np.sqrt(np.mean(np.sum(e[:, :3] ** 2, axis=1)))),
                float(np.sqrt(np.mean(np.sum(e[:, 3:] ** 2, axis=1)))),
                float(np.abs(e).max()),
            ]
        )
    sec.table(
        ["flight", "samples", "duration (s)", "time offset (s)", "yaw (rad)", "position RMS (m)",
         "velocity RMS (m/s)", "max ||e||_inf"],
        rows,
        "Ingested flights (VIO clock; errors after alignment)",
        text_cols=[0],
    )  # fmt: skip
    figs = _flight_figures(data, counter)
    for folder in folders:
        figs += [figure_of(f.run_dir, p, f.rel(p), counter) for p in stage_pngs(folder)]
    sec.figures(figs)
    return sec


_SIM_COLS = (
    ("format", "log"),
    ("duration_s", "duration (s)"),
    ("tracking_rms_m", "tracking RMS (m)"),
    ("perception_error_rms", "||e|| RMS"),
    ("perception_error_max", "||e|| max"),
    ("lipschitz", "true Lipschitz L"),
    ("crashed", "crashed"),
)


def section_simulated(f: Facts, counter: list[int]) -> Section | None:
    import pandas as pd

    folders: list[Path] = f.stages.get("simulate", [])
    if not folders:
        return None
    sec = Section("Simulated flights", id="simulated")
    records = []
    for folder in folders:
        res = read_manifest(folder).get("results", {})
        flat = {k: v for k, v in res.items() if not isinstance(v, dict | list)}
        records.append({"flight": folder.name, **flat})
    full = pd.DataFrame(records)
    cols = [(k, h) for k, h in _SIM_COLS if k in full]
    csv = sec.attach("simulated_flights.csv", full.to_csv(index=False).encode())
    sec.table(
        ["flight", *(h for _, h in cols)],
        full[["flight", *(k for k, _ in cols)]].to_numpy().tolist(),
        "What the simulator knows (truth.json beside each bag)",
        csv=csv,
        text_cols=[0, 1],
    )
    figs = [figure_of(f.run_dir, p, f.rel(p), counter) for d in folders for p in stage_pngs(d)]
    sec.figures(figs)
    return sec
