"""Stage-specific report sections: tables and figures drawn from each stage's files.

Each ``section_<stage>(title, run_dir, folders, counter)`` returns a :class:`Section`, or
``None`` to fall back to the generic one (manifest results and every PNG in the folder).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core.artifacts import figure_bytes, read_manifest
from qsls.pipeline.report.document import Section, add_figures


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

    from qsls.pipeline.ingest.flight import errors, measurements, read_flight, states

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
        add_figures(sec, run_dir, folder, counter)
    return sec


def _yaml(path: Path) -> dict[str, Any]:
    import yaml

    return yaml.safe_load(path.read_text()) if path.is_file() else {}


def section_fit(title: str, run_dir: Path, folders: list[Path], counter: list[int]) -> Section:
    """eps_e and S-slope statistics, the pairs that set the largest slopes, the fit's figures."""
    sec = Section(title)
    for folder in folders:
        em = _yaml(folder / "error_model.yaml")
        if not em:
            continue
        slope = em.get("s_slope", {})
        rows = [["max", em.get("eps_e"), slope.get("max"), ""]]
        for key in sorted(slope.get("percentiles", {}), key=lambda k: float(k[1:])):
            rows.append(
                [
                    key,
                    em.get("eps_e_percentiles", {}).get(key, ""),
                    slope["percentiles"][key],
                    slope.get("local_max_percentiles", {}).get(key, ""),
                ]
            )
        sec.table(
            ["statistic", "eps_e = ||e||", "S over pairs", "S, per-sample max"],
            rows,
            f"Error model ({folder.relative_to(run_dir).as_posix()}): radius r = "
            f"{em.get('radius')}, R0 = {_short(em.get('R0'))}, Delta = {_short(em.get('delta'))}, "
            f"{em.get('n_samples')} samples, {em.get('n_pairs')} pairs",
        )
        worst = em.get("worst_pairs", [])[:10]
        if worst:
            sec.table(
                ["slope", "distance", "flight", "t_i (s)", "t_j (s)", "||e_i||", "||e_j||"],
                [
                    [
                        w["slope"],
                        w["distance"],
                        w["flight"],
                        w["t_i"],
                        w["t_j"],
                        max(abs(v) for v in w["e_i"]),
                        max(abs(v) for v in w["e_j"]),
                    ]
                    for w in worst
                ],
                "The pairs that set the largest S-slopes (where the measurements are at fault)",
            )
        add_figures(sec, run_dir, folder, counter)
    return sec


def _short(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def section_sweep(title: str, run_dir: Path, folders: list[Path], counter: list[int]) -> Section:
    """How many grid points are feasible, the largest feasible S against T, the figures."""
    import pandas as pd

    sec = Section(title)
    for folder in folders:
        if (folder / "sweep.parquet").is_file():
            df = pd.read_parquet(folder / "sweep.parquet")
            counts = df["status"].value_counts().sort_index()
            sec.table(
                ["status", "points"],
                [[k, int(v)] for k, v in counts.items()],
                f"{len(df)} grid points ({folder.relative_to(run_dir).as_posix()})",
            )
        if (folder / "s_max.parquet").is_file():
            sm = pd.read_parquet(folder / "s_max.parquet")
            cols = [
                c for c in ("T", "eps_e", "radius", "delta", "s_max", "min_norm_phi_xy") if c in sm
            ]
            sec.table(
                cols, sm[cols].to_numpy().tolist(), "Largest feasible S (bisection) against T"
            )
        add_figures(sec, run_dir, folder, counter)
    return sec


_CERT_COLS = (
    "status",
    "robust",
    "norm",
    "cost",
    "T",
    "S",
    "eps_e",
    "norm_phi_xx",
    "norm_phi_xy",
    "robustness_lhs",
    "margin",
    "gamma",
    "gamma_strict",
    "achievability_residual",
    "realization_error",
    "solve_time_s",
)


def section_synth(title: str, run_dir: Path, folders: list[Path], counter: list[int]) -> Section:
    """Each controller's certificate, side by side."""
    sec = Section(title)
    for folder in folders:
        rows = []
        for cert_file in sorted(folder.glob("*/certificate.yaml")):
            cert = _yaml(cert_file)
            rows.append([cert_file.parent.name, *(cert.get(c, "") for c in _CERT_COLS)])
        if rows:
            sec.table(
                ["controller", *_CERT_COLS],
                rows,
                "Certificates: 'certified' only when every check passed (achievability <= 1e-7, "
                "the realized controller reproduces its responses to 1e-8, internal stability, "
                "the robustness constraint)",
            )
        add_figures(sec, run_dir, folder, counter)
    return sec


_EVAL_COLS = (
    "flight",
    "controller",
    "gamma",
    "gamma_strict",
    "max_error_norm",
    "frac_under_gamma",
    "frac_under_gamma_strict",
    "max_ratio",
    "max_ratio_t",
    "max_distance_to_training",
    "verdict",
)


def section_evaluate(title: str, run_dir: Path, folders: list[Path], counter: list[int]) -> Section:
    """The bound check per flight and controller; the flown comparison against the paper."""
    import json

    import pandas as pd

    sec = Section(title)
    for folder in folders:
        name = folder.relative_to(run_dir).as_posix()
        if (folder / "per_controller.parquet").is_file():
            pc = pd.read_parquet(folder / "per_controller.parquet")
            cols = [
                c
                for c in (
                    "condition",
                    "controller",
                    "tracking_rms_m",
                    "tracking_max_m",
                    "perception_error_rms",
                    "perception_error_max",
                    "control_effort_rms",
                    "control_smoothness_rms",
                    "crashed",
                )
                if c in pc
            ]
            sec.table(cols, pc[cols].to_numpy().tolist(), f"Controllers flown ({name})")
        ev_json = folder / "evaluation.json"
        if ev_json.is_file():
            comparison = json.loads(ev_json.read_text()).get("comparison") or []
            if comparison:
                sec.table(
                    ["the paper's finding", "qsls", "agrees"],
                    [[c.get("finding"), c.get("qsls"), c.get("agrees")] for c in comparison],
                    "Against the paper's findings",
                )
        if (folder / "evaluation.parquet").is_file():
            ev = pd.read_parquet(folder / "evaluation.parquet")
            cols = [c for c in _EVAL_COLS if c in ev]
            sec.table(
                cols, ev[cols].to_numpy().tolist(), f"Bound check: ||e_k|| against gamma ({name})"
            )
        add_figures(sec, run_dir, folder, counter)
    return sec


def section_simulate(title: str, run_dir: Path, folders: list[Path], counter: list[int]) -> Section:
    """One row per simulated flight: what the simulator knows (the truth behind the logs)."""
    sec = Section(title)
    rows, keys = [], []
    for folder in folders:
        res = read_manifest(folder).get("results", {})
        flat = {k: v for k, v in res.items() if not isinstance(v, dict | list)}
        keys = keys or [k for k in flat if k != "crash_reason"]
        rows.append([folder.relative_to(run_dir).as_posix(), *(flat.get(k, "") for k in keys)])
    sec.table(["flight", *keys], rows, "Simulated flights (truth.json beside each bag)")
    for folder in folders:
        add_figures(sec, run_dir, folder, counter)
    return sec
