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
