"""The status_reason table stays readable at 1280 px (issue 50): one reason a row, wrapped
in a wide column, every row under 80 px tall and within the page (a whole reason on one row
was 247 px tall wrapped, or thousands of px wide unwrapped)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from qsls.pipeline.report.certificates import reason_parts
from tests.browser import find_chromium, visit

REPO = Path(__file__).resolve().parents[1]


def test_reason_parts_keep_a_fix_with_its_reason():
    reason = (
        "not calibrated: the premise describes the design flights only; S cannot be tested: "
        "no two flights share a room; certifiable with a second flight there; eps_w cannot be "
        "measured: no inputs; certifiable with the commands logged"
    )
    assert reason_parts(reason) == [
        "not calibrated: the premise describes the design flights only",
        "S cannot be tested: no two flights share a room; certifiable with a second flight there",
        "eps_w cannot be measured: no inputs; certifiable with the commands logged",
    ]
    assert reason_parts("one plain reason") == ["one plain reason"]


@pytest.mark.real
@pytest.mark.skipif(find_chromium() is None, reason="chromium is not installed")
def test_the_euroc_reasons_table_rows_fit(real_data, tmp_path):
    shutil.copytree(REPO / "configs", tmp_path / "configs")
    cfg = tmp_path / "configs" / "euroc.yaml"
    data = yaml.safe_load(cfg.read_text())
    data["stages"] = ["ingest", "fit", "synth", "report"]  # the certificates and the report
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    env = {**os.environ, "QSLS_SHARED": str(real_data.parent.parent)}
    proc = subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", "run", str(cfg)],
        cwd=tmp_path, env=env, capture_output=True, text=True,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = tmp_path / "runs" / "euroc" / "report"
    page = visit(out / "index.html", tmp_path / "shot.png")
    rows = [r for r in page.layout["rows"] if "cannot be" in r["text"]]
    assert len(rows) >= 3, [r["text"] for r in page.layout["rows"]]
    assert max(r["height"] for r in rows) < 80, rows
    assert max(r["width"] for r in rows) <= 1160, rows  # main's width: no sideways scroll
