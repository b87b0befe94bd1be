"""Fault injection (issue 35): ``qsls run configs/quickstart.yaml`` killed with SIGKILL at two
moments (mid simulate; during fly, with its worker processes), then rerun: each rerun redoes
only what was unfinished, leaves no temporary and no lock, and the finished run's data files
are byte-identical to those of the session's clean quickstart run (``quickstart_session``,
shared with test_run.py; paths normalized). About 30 s (one quickstart and the killed parts)."""

from __future__ import annotations

import glob
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.test_run import QUICKSTART, _data_files, _statuses


def _cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "qsls.cli.main", *args]


def _kill_when(work: Path, pattern: str, delay: float) -> None:
    """Start the run, SIGKILL its process group ``delay`` s after ``pattern`` exists."""
    proc = subprocess.Popen(
        _cmd("run", str(work / "quickstart.yaml")), cwd=work, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 240
        while not glob.glob(str(work / pattern)):
            assert proc.poll() is None, f"the run ended before {pattern} appeared"
            assert time.monotonic() < deadline, f"{pattern} never appeared"
            time.sleep(0.02)
        time.sleep(delay)
        assert proc.poll() is None, "the run ended before it could be killed"
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(30)


def _leftovers(run: Path) -> list[str]:
    return sorted(
        p.relative_to(run).as_posix()
        for p in run.rglob(".*")
        if ".tmp-" in p.name or ".old-" in p.name or p.name.endswith(".lock")
    ) + [p.name for p in run.parent.glob(".*.lock")]


def _normalized(files: dict[str, bytes], cfg: Path, work: Path) -> dict[str, bytes]:
    """Data files with the run's own config path and work folder written as placeholders."""
    return {
        k: v.replace(str(cfg).encode(), b"CONFIG").replace(str(work).encode(), b"WORK")
        for k, v in files.items()
    }


@pytest.mark.slow
def test_sigkill_mid_run_then_rerun_gives_byte_identical_data(tmp_path, quickstart_session):
    clean_work, clean_cfg, _, _, clean_files = quickstart_session
    work = tmp_path
    cfg = work / "quickstart.yaml"
    cfg.write_text(QUICKSTART.read_text())
    run = work / "runs" / "quickstart"

    # 1. mid simulate: train_2's bag is being written after train_1 published
    _kill_when(work, "runs/quickstart/simulate/train_1/manifest.json", 0.3)
    done = json.loads((run / "run_state.json").read_text())["stages"]
    assert "simulate/train_1" in done and "fit" not in done

    # 2. during fly: its worker processes flying the controllers
    _kill_when(work, "runs/quickstart/.fly.tmp-*", 0.5)
    assert list(run.glob(".fly.tmp-*")), "SIGKILL leaves the stage's temporary behind"
    assert not (run / "fly").exists()

    # 3. the rerun finishes exactly what was unfinished and cleans up after the killed runs
    done = subprocess.run(_cmd("run", str(cfg)), cwd=work, capture_output=True,
                          text=True)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    statuses = _statuses(done.stderr)
    ran = {k for k, v in statuses.items() if v == "ran"}
    assert ran == {"fly"}, statuses
    assert _leftovers(run) == []
    resumed = _normalized(_data_files(work), cfg, work)
    assert len(resumed) > 40

    # 4. the same bytes as a clean run of the same config
    clean = _normalized(clean_files, clean_cfg, clean_work)
    assert sorted(clean) == sorted(resumed)
    assert [k for k in clean if clean[k] != resumed[k]] == []
