"""A full disk is one line, never a traceback (issue 35): on a real tmpfs too small for the
run, and on one already 100 % full (no empty lock file left). Then, with space again, the
run completes. Needs root to mount a tmpfs (skipped otherwise)."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

TINY = {
    "name": "tiny",
    "stages": ["simulate"],
    "simulate": {"duration": 5.0},
    "flights": [{"name": "f1", "role": "train", "simulate": {"seed": 1}}],
    "report": False,
}


@pytest.fixture
def small_fs(tmp_path):
    """A 100 kB tmpfs (a simulated flight's bag alone is bigger)."""
    mnt = tmp_path / "fs"
    mnt.mkdir()
    proc = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=100k", "tmpfs", str(mnt)], capture_output=True
    )
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({proc.stderr.decode().strip()})")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


def _run(cfg: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", "run", str(cfg), "--out", str(out)],
        capture_output=True, text=True, cwd=cfg.parent,
    )  # fmt: skip


def _one_line(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode != 0 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("error")]
    assert len(lines) == 1, proc.stderr
    return lines[0]


def _leftovers(root: Path) -> list[Path]:
    return [p for p in root.rglob(".*") if ".tmp-" in p.name or ".old-" in p.name or
            p.name.endswith(".lock")]  # fmt: skip


def test_a_disk_that_fills_up_mid_run_is_one_line_and_the_rerun_completes(small_fs, tmp_path):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    line = _one_line(_run(cfg, small_fs / "run"))
    assert "No space left on device" in line and "free some space" in line
    assert _leftovers(small_fs) == []
    subprocess.run(["mount", "-o", "remount,size=20m", str(small_fs)], check=True)
    again = _run(cfg, small_fs / "run")
    assert again.returncode == 0, again.stderr[-2000:]
    assert (small_fs / "run" / "simulate" / "f1" / "manifest.json").is_file()


def test_a_full_disk_leaves_no_empty_lock_file(small_fs, tmp_path):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    (small_fs / "run").mkdir()
    fd = os.open(small_fs / "fill", os.O_WRONLY | os.O_CREAT)
    try:  # fill it to the last byte
        for size in (4096, 1):
            while os.write(fd, b"\0" * size) == size:
                pass
    except OSError:
        with contextlib.suppress(OSError):
            while os.write(fd, b"\0"):
                pass
    finally:
        os.close(fd)
    line = _one_line(_run(cfg, small_fs / "run"))
    assert "No space left on device" in line
    assert _leftovers(small_fs) == [] and list((small_fs / "run").iterdir()) == []
