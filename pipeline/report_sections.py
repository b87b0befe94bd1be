"""Stage-specific report sections: tables and figures drawn from each stage's files.

Each ``section_<stage>(title, run_dir, folders, counter)`` returns a :class:`Section`, or
``None`` to fall back to the generic one (manifest results and every PNG in the folder).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.artifacts import figure_bytes, read_manifest
from qsls.pipeline.report import Section, _add_figures


def _fig(sec: Section, counter: list[int], stem: str, fig: Any, caption: str) -> None:
    import matplotlib.pyplot as plt

    counter[0] += 1
    try:
        sec.figure(f"fig{counter[0]:02d}_{stem}.png", figure_bytes(fig, "png", 100), caption)
    finally:
        plt.close(fig)


def section_ingest(title: str, run_dir: Path, folders: list[Path], counter: list[int]) -> Section:
    """Per flight: samples, offset, alignment, RMS errors; trajectories and ||e|| over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from qsls.pipeline.flight import errors, measurements, read_flight, states

    sec = Section(title)
    rows = []
    fig_xy, ax_xy = plt.subplots(figsize=(6.5, 5))
    fig_e, ax_e = plt.subplots(figsize=(8, 3.2))
    for folder in folders:
        name = folder.relative_to(run_dir).as_posix()
        res = read_manifest(folder).get("results", {})
        df = read_flight(folder)
        x, y, e = states(df), measurements(df), errors(df)
        en = np.abs(e).max(axis=1)
        rows.append(
            [
                name,
                len(df),
                res.get("time_offset_s", float("nan")),
                (res.get("alignment") or {}).get("yaw_rad", float("nan")),
                float(np.sqrt(np.mean(np.sum(e[:, :3] ** 2, axis=1)))),
                float(np.sqrt(np.mean(np.sum(e[:, 3:] ** 2, axis=1)))),
                float(en.max()),
            ]
        )
        (line,) = ax_xy.plot(x[:, 0], x[:, 1], lw=1.2, label=f"{name} truth")
        ax_xy.plot(y[:, 0], y[:, 1], lw=0.8, ls="--", color=line.get_color(), label=f"{name} VIO")
        ax_e.plot(df["t"].to_numpy(), en, lw=0.9, label=name)
    sec.table(
        [
            "flight",
            "samples",
            "time offset (s)",
            "yaw (rad)",
            "pos RMS (m)",
            "vel RMS (m/s)",
            "max ||e||",
        ],
        rows,
        "Ingested flights (VIO clock; errors after alignment)",
    )
    ax_xy.set_xlabel("x (m)")
    ax_xy.set_ylabel("y (m)")
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_xy.legend(fontsize=6, ncol=2)
    ax_xy.set_title("Trajectories: truth (solid) and VIO (dashed)")
    fig_xy.tight_layout()
    _fig(sec, counter, "flights_xy", fig_xy, "Trajectories of every ingested flight")
    ax_e.set_xlabel("t (s)")
    ax_e.set_ylabel("||e||_inf")
    ax_e.legend(fontsize=6, ncol=3)
    ax_e.set_title("Perception error over time")
    fig_e.tight_layout()
    _fig(
        sec, counter, "flights_error", fig_e, "Perception error ||e_k|| (infinity norm) per flight"
    )
    for folder in folders:
        _add_figures(sec, run_dir, folder, counter)
    return sec
