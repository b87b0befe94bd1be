"""The report's camera section: the VIO emulator and the camera loop side by side.

Appears when the run has camera flights (a simulate folder whose ``truth.json`` names the
``msckf`` estimator, or a fly stage flown with ``vio: camera``). It shows

- the simulated flights paired by perception condition and seed, emulator beside camera
  (perception error, tracking, and the camera loop's own counters: features per frame, blur,
  filter resets);
- the fly stage's per-controller results of the camera loop, per condition; when the fly
  stage flew both estimators (``vio: [camera, emulator]``), each controller's closed-loop
  results with the camera loop beside those with the emulator (same seeds and conditions:
  :mod:`qsls.pipeline.fly.estimators`), the guarantee's assumptions per estimator and
  each finding's verdict per estimator, the per-flight pairs attached as CSV (otherwise the
  emulator's counterpart is ``configs/paper_sim.yaml``'s run);
- one frame of each condition with the features tracked on it (``camera_frame.npz`` of a
  camera simulate folder, drawn here).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core import style
from qsls.pipeline.core.artifacts import figure_bytes, read_manifest
from qsls.pipeline.fly.estimators import PAIRED_FILE, estimator_ratios
from qsls.pipeline.report.document import Figure, Section
from qsls.pipeline.report.facts import Facts
from qsls.pipeline.sim.simulate import CAMERA_FRAME, TRUTH_FILE


def _simulated(f: Facts) -> list[dict[str, Any]]:
    """One record per simulate folder: its estimator, condition, seed and results."""
    rows = []
    for folder in f.stages.get("simulate", []):
        truth_file = folder / TRUTH_FILE
        if not truth_file.is_file():
            continue
        truth = json.loads(truth_file.read_text())
        emu = truth.get("emulator", {})
        res = read_manifest(folder).get("results", {})
        camera = emu.get("estimator") == "msckf"
        rows.append(
            {
                "folder": folder,
                "flight": folder.name,
                "estimator": "camera (MSCKF)" if camera else "emulator",
                "camera": camera,
                "condition": emu.get("params", {}).get("perception", "?"),
                "seed": truth.get("seed"),
                "e_rms": res.get("perception_error_rms"),
                "e_max": res.get("perception_error_max"),
                "tracking_rms": res.get("tracking_rms_m"),
                "crashed": res.get("crashed"),
                "features": emu.get("features_per_frame") if camera else None,
                "blur": emu.get("blur_px_mean") if camera else None,
                "resets": emu.get("resets") if camera else None,
            }
        )
    return rows


def _fly_estimators(f: Facts) -> list[str]:
    """The estimators the fly stage flew with, the primary first (none without a fly stage)."""
    if not f.fly_folder:
        return []
    vio = read_manifest(f.run_dir / f.fly_folder).get("options", {}).get("vio", "emulator")
    return list(vio) if isinstance(vio, list) else [str(vio)]


ESTIMATOR_METRICS = {
    "tracking_rms_m": "tracking RMS (m)",
    "perception_error_rms": "||e|| RMS",
    "perception_error_max": "||e|| max",
    "crashed": "crashed",
}


def _side_by_side(f: Facts, sec: Section, vios: list[str]) -> None:
    """The fly stage's controllers with each estimator beside each other, over the flights
    paired by controller, condition and seed (module docstring)."""
    import pandas as pd

    path = f.run_dir / f.fly_folder / PAIRED_FILE
    if not path.is_file():
        return
    pairs = pd.read_parquet(path)
    if not len(pairs):
        return
    csv = sec.attach(
        f"paired_by_estimator_{f.fly_folder.replace('/', '_')}.csv",
        pairs.to_csv(index=False, float_format="%.6g").encode(),
    )
    g = pairs.groupby(["condition", "controller"], sort=False)
    cols, parts = ["condition", "controller", "seeds"], [g.size().rename("seeds")]
    for m, label in ESTIMATOR_METRICS.items():
        for vio in vios:
            c = g[f"{m}_{vio}"]
            parts.append((c.sum() if m == "crashed" else c.mean()).rename(f"{m}_{vio}"))
            cols.append(f"{label} {vio}")
    for vio in vios:
        held = g[f"assumptions_hold_{vio}"].agg(_held_count).rename(f"held_{vio}")
        parts.append(held)
        cols.append(f"assumptions held {vio}")
    wide = pd.concat(parts, axis=1).reset_index()
    ratios = estimator_ratios(pairs, vios[0], vios[1])
    for m, label in (("tracking_rms_m", "tracking RMS"), ("perception_error_rms", "||e|| RMS")):
        ratios[f"{m}_text"] = [_ratio_text(r, m) for r in ratios.to_dict(orient="records")]
        wide = wide.merge(ratios[["condition", "controller", f"{m}_text"]], how="left")
        cols.append(f"{label} {vios[0]} / {vios[1]} [95% CI]")
    sec.table(
        cols,
        wide.to_numpy().tolist(),
        f"Controllers flown with each estimator ({f.fly_folder}), paired by seed and "
        "condition: means over the seeds (crashes summed); assumptions held: the flights on "
        "which every assumption of the controller's guarantee held (- without a guarantee); "
        "the ratios: geometric mean over seeds of the per-seed ratio with its 95% interval "
        "(1: no difference)",
        csv=csv,
        text_cols=[0, 1, *range(len(cols) - len(vios) - 2, len(cols))],
    )
    by = (f.findings or {}).get("by_estimator") or {}
    rows: dict[str, list[Any]] = {}
    for j, vio in enumerate(vios):
        for item in by.get(vio, {}).get("findings", []):
            head = f"{item['id']}. {item['claim']}"
            rows.setdefault(str(item["id"]), [head] + ["-"] * len(vios))[1 + j] = item["verdict"]
    if rows:
        sec.table(
            ["finding", *vios], list(rows.values()),
            "The paper's findings per estimator, each paired by seed within its estimator",
            text_cols=list(range(1 + len(vios))),
        )  # fmt: skip


def _ratio_text(r: dict[str, Any], m: str) -> str:
    """``0.81 [0.72, 0.9]``; the interval left out with one seed; ``(k of n seeds)`` when
    pairs were dropped (a non-positive or missing metric)."""
    import math

    ratio, lo, hi = r[f"{m}_ratio"], r[f"{m}_lo"], r[f"{m}_hi"]
    if not math.isfinite(ratio):
        return "-"
    used, total = r.get(f"{m}_n", r.get("n")), r.get("n")
    dropped = f" ({used} of {total} seeds)" if used is not None and used != total else ""
    return f"{ratio:.3g}" + (f" [{lo:.3g}, {hi:.3g}]" if math.isfinite(lo) else "") + dropped


def _held_count(h: Any) -> str:
    """``k of n`` flights on which every assumption held, ``-`` when none was checked."""
    h = h.dropna()
    return f"{int(h.astype(bool).sum())} of {len(h)}" if len(h) else "-"


def _frames_figure(frames: list[tuple[str, Path]], counter: list[int]) -> Figure:
    """The kept frames side by side, tracked features circled."""
    import matplotlib.pyplot as plt

    fig, ax = style.subplots(1, len(frames), width=style.WIDTH_IN, height=2.6)
    for a, (cond, path) in zip(ax[0], frames, strict=True):
        d = np.load(path)
        pts = d["points"]
        a.imshow(d["image"], cmap="gray", vmin=0, vmax=255, interpolation="nearest")
        if len(pts):
            a.scatter(pts[:, 0], pts[:, 1], s=14, facecolors="none", edgecolors="#e8552d", lw=0.8)
        a.set_title(f"{cond}: t = {float(d['t_s']):g} s, {len(pts)} features", loc="left")
        a.set_xticks([])
        a.set_yticks([])
    counter[0] += 1
    try:
        png = figure_bytes(fig, "png", 110)
    finally:
        plt.close(fig)
    caption = (
        "One camera frame per perception condition with the features the tracker holds on "
        "it (circles): degraded light means a longer exposure (more blur), more noise and a "
        "weaker texture"
    )
    return Figure(f"fig{counter[0]:02d}_camera_frames.png", png, caption)


def section_camera(f: Facts, counter: list[int]) -> Section | None:
    """The section of the module docstring, or None when the run has no camera flights."""
    sims = _simulated(f)
    vios = _fly_estimators(f)
    fly_camera = "camera" in vios
    if not fly_camera and not any(r["camera"] for r in sims):
        return None
    sec = Section("Camera loop beside the emulator", id="camera")
    sec.text(
        "Flights whose estimate comes from a rendered camera, a 200 Hz IMU and an MSCKF "
        "(docs/camera.md) beside flights with the VIO emulator's designed errors: same "
        "controller, seed and perception condition."
    )
    keyed = sorted(sims, key=lambda r: (str(r["condition"]), r["seed"] or 0, r["estimator"]))
    if keyed:
        sec.table(
            ["condition", "seed", "flight", "estimator", "||e|| RMS", "||e|| max",
             "tracking RMS (m)", "crashed", "features / frame", "blur (px)", "resets"],
            [[r["condition"], r["seed"], r["flight"], r["estimator"], r["e_rms"], r["e_max"],
              r["tracking_rms"], r["crashed"], r["features"], r["blur"], r["resets"]]
             for r in keyed],
            "Simulated flights, emulator and camera loop side by side",
            text_cols=[0, 2, 3],
        )  # fmt: skip
    per = f.per_controller
    if fly_camera and len(vios) > 1:
        _side_by_side(f, sec, vios)
    elif fly_camera and per is not None and len(per):
        cols = [c for c in ("condition", "controller", "tracking_rms_m", "perception_error_rms",
                            "perception_error_max", "crashed", "flights") if c in per]  # fmt: skip
        sec.table(
            cols,
            per[cols].to_numpy().tolist(),
            f"Controllers flown with the camera loop ({f.fly_folder}); the emulator's run of the "
            "same experiment: configs/paper_sim.yaml",
            text_cols=[0, 1],
        )
    frames: dict[str, Path] = {}
    for r in sims:
        path = r["folder"] / CAMERA_FRAME
        if r["camera"] and path.is_file():
            frames.setdefault(str(r["condition"]), path)
    if frames:
        order = sorted(frames, key=lambda c: (c != "regular", c))
        sec.figures([_frames_figure([(c, frames[c]) for c in order], counter)])
    return sec
