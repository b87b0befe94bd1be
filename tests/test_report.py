"""qsls report: deterministic bytes, and the page as a reader sees it in headless Chromium."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.core.artifacts import StageWriter
from qsls.pipeline.ingest.flight import make_flight_frame

from .browser import find_chromium, visit


def _fake_run(root):
    rng = np.random.default_rng(0)
    for i in range(2):
        t = np.arange(300, dtype=np.int64) * 100_000_000
        th = t * 1e-9 * 0.8
        x = np.c_[
            np.cos(th), np.sin(th), np.ones_like(th), -0.8 * np.sin(th), 0.8 * np.cos(th), 0 * th
        ]
        y = x + 0.02 * rng.standard_normal(x.shape)
        with StageWriter(root / "ingest" / f"flight{i}", "ingest", options={"dt": 0.1}) as w:
            w.write_parquet("flight.parquet", make_flight_frame(t, x, y))
            w.results["time_offset_s"] = 0.01 * i
    return root


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory):
    root = _fake_run(tmp_path_factory.mktemp("run") / "demo")
    out = tmp_path_factory.mktemp("rep") / "demo"
    res = CliRunner().invoke(app, ["report", str(root), "--out", str(out)])
    assert res.exit_code == 0, res.output
    return root, out


def test_report_is_byte_identical_and_refuses_overwrite(report_dir, tmp_path):
    root, out = report_dir
    again = tmp_path / "again"
    assert CliRunner().invoke(app, ["report", str(root), "--out", str(again)]).exit_code == 0
    for name in ("index.html", "report.md"):
        assert (out / name).read_bytes() == (again / name).read_bytes()
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in again.iterdir())
    res = CliRunner().invoke(app, ["report", str(root), "--out", str(again)])
    assert res.exit_code != 0 and "--force" in res.output


def test_report_on_a_folder_that_is_not_a_run(tmp_path):
    res = CliRunner().invoke(app, ["report", str(tmp_path), "--out", str(tmp_path / "r")])
    assert res.exit_code == 2 and "no stage folders" in res.output
    assert not (tmp_path / "r").exists()


@pytest.mark.skipif(find_chromium() is None, reason="chromium is not installed")
def test_report_renders_in_chromium_offline(report_dir):
    _, out = report_dir
    shot = out.parent / "screenshot.png"
    page = visit(out / "index.html", shot)
    assert page.title.startswith("qsls report")
    assert len(page.image_sizes) >= 2
    assert all(w > 0 and h > 0 for w, h in page.image_sizes), page.image_sizes
    left = [u for u in page.requests if not u.startswith(("file:", "data:"))]
    assert left == [], f"requests left the file: {left}"
    assert page.console_errors == []
    assert shot.stat().st_size > 10_000 and shot.read_bytes()[:4] == b"\x89PNG"
