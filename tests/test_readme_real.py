"""The README's real-data commands (section "Real flights: EuRoC"), run as they are written
from a fresh clone's layout: the repository's configs in a folder with ``../shared`` beside
it (skipped when ../shared/data/real is absent), then from elsewhere through QSLS_SHARED."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
MARK = "<!-- real-data commands: tests/test_readme_real.py -->"


def readme_commands() -> str:
    """The bash block that follows the marker in README.md."""
    text = (REPO / "README.md").read_text()
    block = re.search(re.escape(MARK) + r"\s*```bash\n(.*?)```", text, re.S)
    assert block, "README.md lost its real-data block"
    return block.group(1)


def run_block(cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    qsls = f"{sys.executable} -m qsls.cli.main"
    script = "set -e\nqsls() { " + qsls + ' "$@"; }\n' + readme_commands()
    return subprocess.run(
        ["bash", "-c", script], cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )


@pytest.mark.real
def test_the_readmes_real_data_commands_work_from_a_fresh_clone(real_data, tmp_path):
    clone = tmp_path / "qsls"
    shutil.copytree(REPO / "configs", clone / "configs")
    (tmp_path / "shared").symlink_to(real_data.parent.parent, target_is_directory=True)
    env = {k: v for k, v in os.environ.items() if k != "QSLS_SHARED"}
    proc = run_block(clone, env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    # the run: the position-weighted model's controllers checked on the held-out flight
    ev = json.loads((clone / "runs/euroc/evaluate/evaluation.json").read_text())
    assert {r["controller"] for r in ev["rows"]} >= {"l1_robust", "pd"}
    mh04 = json.loads((clone / "runs/euroc-mh04/evaluation.json").read_text())
    robust = [r for r in mh04["rows"] if r["controller"] == "l1_robust"]
    assert robust and robust[0]["frac_premise_holds"] == 1.0  # a training flight: eps is its max
    # the infeasible synth wrote the feasible controllers and named the others
    written = sorted(p.name for p in (clone / "ctrl").iterdir() if p.is_dir())
    assert written == ["l1_nominal", "pd"]
    results = json.loads((clone / "ctrl/manifest.json").read_text())["results"]
    assert sorted(results["infeasible"]) == ["l1_robust", "l1_robust_imitation"]
    assert "no S >= 0 is feasible" in proc.stderr
    cert = yaml.safe_load((clone / "ctrl-euroc/l1_robust/certificate.yaml").read_text())
    assert cert["status"] == "relaxed" and cert["T"] == 40 and cert["measure"] == "position"


@pytest.mark.real
def test_real_data_elsewhere_is_named_by_qsls_shared(real_data, tmp_path):
    clone = tmp_path / "somewhere" / "qsls"
    shutil.copytree(REPO / "configs", clone / "configs")
    env = {k: v for k, v in os.environ.items() if k != "QSLS_SHARED"}
    cmd = [sys.executable, "-m", "qsls.cli.main", "run", "configs/euroc.yaml"]
    lost = subprocess.run(cmd, cwd=clone, env=env, capture_output=True, text=True)
    assert lost.returncode == 2 and "Traceback" not in lost.stderr
    line = lost.stderr.strip()
    assert len(line.splitlines()) == 1
    assert "QSLS_SHARED is not set" in line and "set QSLS_SHARED to the folder" in line, line
    assert not (clone / "runs").exists()
    env["QSLS_SHARED"] = str(real_data.parent.parent)
    cfg = yaml.safe_load((clone / "configs/euroc.yaml").read_text())
    cfg["stages"] = ["ingest"]  # the paths are what is tested here
    (clone / "configs/euroc.yaml").write_text(yaml.safe_dump(cfg))
    found = subprocess.run(cmd, cwd=clone, env=env, capture_output=True, text=True)
    assert found.returncode == 0, found.stderr[-2000:]
    assert (clone / "runs/euroc/ingest/v102/flight.parquet").is_file()
