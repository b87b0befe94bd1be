"""The camera loop through the command line: simulate -> ingest, refusals, qsls run."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def _qsls(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", *args], cwd=cwd, capture_output=True, text=True
    )


def test_simulate_camera_bag_is_ingested(tmp_path):
    """``qsls simulate --vio camera`` writes a bag ``qsls ingest`` reads; its errors are the
    MSCKF's (no emulator bias field, so no true Lipschitz constant is claimed), finite,
    centimetre-sized."""
    sim = _qsls(
        "simulate",
        "--out",
        "sim",
        "--vio",
        "camera",
        "--duration",
        "8",
        "--seed",
        "4",
        cwd=tmp_path,
    )
    assert sim.returncode == 0, sim.stderr[-2000:]
    truth = json.loads((tmp_path / "sim" / "truth.json").read_text())
    assert truth["lipschitz"] is None
    assert truth["emulator"]["estimator"] == "msckf" and truth["emulator"]["frames"] == 161
    ing = _qsls("ingest", "sim/flight.bag", "--out", "flight", cwd=tmp_path)
    assert ing.returncode == 0, ing.stderr[-2000:]
    import pandas as pd

    df = pd.read_parquet(tmp_path / "flight" / "flight.parquet")
    e = df[[c for c in df.columns if c.startswith("e_")]].to_numpy()
    assert np.isfinite(e).all() and len(e) > 60
    assert 0.001 < np.sqrt((e[:, :3] ** 2).mean()) < 0.1
    # the recorded clock offset is recovered from the camera loop's estimate too
    man = json.loads((tmp_path / "flight" / "manifest.json").read_text())
    assert abs(man["results"]["time_offset_s"] - truth["time_offset_s"]) < 0.01


def test_simulate_camera_same_seed_same_bag(tmp_path):
    for out in ("a", "b"):
        proc = _qsls("simulate", "--out", out, "--vio", "camera", "--duration", "3", cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "a" / "flight.bag").read_bytes() == (
        tmp_path / "b" / "flight.bag"
    ).read_bytes()


@pytest.mark.parametrize(
    ("args", "config", "message"),
    [
        (
            ["--perception", "foggy"],
            None,
            "'vio.perception': Input should be 'regular' or 'degraded'",
        ),
        (["--vio", "lidar"], None, "'vio.kind': Input should be 'emulator' or 'camera'"),
        (
            ["--vio", "camera"],
            "vio: {camera: {pitch_deg: 180}}",
            "sees a textured plane on 0% of its image",
        ),
        (["--vio", "camera"], "vio: {camera: {width: 752, height: 480}}", "speed budget"),
    ],
)
def test_bad_camera_input_is_one_line(tmp_path, args, config, message):
    extra = []
    if config:
        (tmp_path / "c.yaml").write_text(config + "\n")
        extra = ["--config", "c.yaml"]
    proc = _qsls("simulate", "--out", "sim", *args, *extra, cwd=tmp_path)
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], proc.stderr
    assert not (tmp_path / "sim").exists()


@pytest.mark.slow
def test_run_ci_camera_config(tmp_path):
    """configs/ci_camera.yaml (paper_sim_camera shortened: one seed, short flights) runs
    every stage with the camera loop and writes the fly stage's findings."""
    proc = _qsls("run", str(REPO / "configs" / "ci_camera.yaml"), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "runs" / "ci_camera"
    findings = json.loads((run / "fly" / "findings.json").read_text())
    assert findings["findings"]
    import pandas as pd
    import yaml

    flights = pd.read_parquet(run / "fly" / "flights.parquet")
    assert len(flights) == 10 and not flights["ingest_error"].astype(bool).any()
    sim = json.loads((run / "simulate" / "train_1" / "truth.json").read_text())
    assert sim["emulator"]["estimator"] == "msckf"
    # camera flights claim no true Lipschitz constant, so finding 3 does not quote one
    assert "true Lipschitz" not in (run / "fly" / "comparison.md").read_text()
    # the report puts the emulator and camera held-out flights side by side, with frames
    md = (run / "report" / "report.md").read_text()
    sec = md[md.index("## Camera loop beside the emulator") :]
    assert "heldout_1_emulator | emulator" in sec and "heldout_1 | camera (MSCKF)" in sec
    assert "camera_frames.png" in sec
    # the fly stage flew both estimators: the controllers' results side by side, paired by seed
    assert (
        "Controllers flown with each estimator" in sec and "| finding | camera | emulator |" in sec
    )
    pairs = pd.read_parquet(run / "fly" / "paired_by_estimator.parquet")
    assert len(pairs) == 10 and pairs["tracking_rms_m_emulator"].notna().all()
    assert json.loads((run / "fly" / "findings.json").read_text())["estimator"] == "camera"
    # the honest premise fitted on the camera loop's training flights (PD at 10 Hz, inputs
    # logged, so eps_w is the realized disturbance) certifies the robust controller
    cert = yaml.safe_load((run / "synth" / "l1_robust" / "certificate.yaml").read_text())
    assert cert["status"] == "relaxed" and cert["checks"]["robustness"]["passed"], cert
    assert cert["premise"]["eps_w"]["chosen"] == "max" and cert["S"] == 0.0
    assert cert["rho_star"] <= cert["radius"] and cert["tested_range"] > 0.2
