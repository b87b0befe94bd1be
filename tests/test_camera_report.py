"""The report's camera section: emulator and camera flights side by side, one frame per
condition with its tracked features."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from qsls.pipeline.sim.simulate import CAMERA_FRAME, SimOptions, simulate


def _sim(run: Path, name: str, kind: str, perception: str) -> None:
    opts = SimOptions.model_validate(
        {
            "seed": 3,
            "duration": 1.5,
            "vio": {"kind": kind, "perception": perception, "camera": {"snapshot_s": 1.0}},
        }
    )
    simulate(opts, run / "simulate" / name)


def test_camera_section_side_by_side_with_frames(tmp_path):
    from qsls.pipeline.report.stage import report

    run = tmp_path / "run"
    _sim(run, "cam_regular", "camera", "regular")
    _sim(run, "cam_degraded", "camera", "degraded")
    _sim(run, "emu_regular", "emulator", "regular")
    frame = np.load(run / "simulate" / "cam_regular" / CAMERA_FRAME)
    assert frame["image"].shape == (240, 376) and frame["image"].dtype == np.uint8
    assert float(frame["t_s"]) == 1.0 and len(frame["points"]) > 10
    assert not (run / "simulate" / "emu_regular" / CAMERA_FRAME).exists()
    # degraded: weaker texture and a higher gain, a frame of lower contrast
    dark = np.load(run / "simulate" / "cam_degraded" / CAMERA_FRAME)
    assert dark["image"].std() < frame["image"].std()

    res = report(run)
    md = (res.out / "report.md").read_text()
    sec = md[md.index("## Camera loop beside the emulator") :]
    rows = [line for line in sec.splitlines() if line.startswith("| regular") or
            line.startswith("| degraded")]  # fmt: skip
    assert len(rows) == 3
    assert any("emu_regular | emulator" in r for r in rows)
    assert any("cam_regular | camera (MSCKF)" in r for r in rows)
    pngs = sorted(p.name for p in res.out.glob("*camera_frames.png"))
    assert len(pngs) == 1 and f"({pngs[0]})" in sec
    first = (res.out / pngs[0]).read_bytes()
    again = report(run, force=True)
    assert (again.out / pngs[0]).read_bytes() == first  # deterministic


def test_no_camera_section_without_camera_flights(tmp_path):
    from qsls.pipeline.report.stage import report

    run = tmp_path / "run"
    _sim(run, "emu_regular", "emulator", "regular")
    md = (report(run).out / "report.md").read_text()
    assert "Camera loop" not in md


def test_estimator_ratio_counts_the_pairs_it_dropped():
    """A pair with a missing (NaN) or zero metric cannot enter a log ratio: it is dropped,
    and the report's cell says how many seeds the ratio rests on."""
    import numpy as np
    import pandas as pd
    import pytest

    from qsls.pipeline.fly.estimators import estimator_ratios
    from qsls.pipeline.report.camera import _ratio_text

    pairs = pd.DataFrame({
        "condition": "regular", "controller": "pd", "seed": [0, 1, 2, 3],
        "tracking_rms_m_camera": [0.05, 0.04, np.nan, 0.06],
        "tracking_rms_m_emulator": [0.10, 0.08, 0.09, 0.12],
        "perception_error_rms_camera": [0.02, 0.02, 0.03, 0.02],
        "perception_error_rms_emulator": [0.08, 0.08, 0.09, 0.0],
    })  # fmt: skip
    r = estimator_ratios(pairs, "camera", "emulator").iloc[0].to_dict()
    assert r["n"] == 4 and r["tracking_rms_m_n"] == 3 and r["perception_error_rms_n"] == 3
    assert r["tracking_rms_m_ratio"] == pytest.approx(0.5)
    assert r["perception_error_rms_ratio"] == pytest.approx(
        np.exp(np.mean(np.log([0.25, 0.25, 1 / 3])))
    )
    assert _ratio_text(r, "tracking_rms_m").endswith("(3 of 4 seeds)")
