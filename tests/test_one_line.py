"""Refusals that were tracebacks or went unchecked (issue 35), each one line with a non-zero
exit naming the cause: a config that is not UTF-8, a YAML alias bomb, a run name that walks
out of runs/, a flight name with a newline, a run_state.json or run.json that is a folder or
binary."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from tests.test_user_files import TINY, _one_line_refusal


def _qsls(*args: object, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", *map(str, args)],
        cwd=cwd, capture_output=True, text=True, timeout=timeout,
    )  # fmt: skip


def test_a_config_that_is_not_utf8_is_one_line(tmp_path):
    cfg = tmp_path / "latin1.yaml"
    cfg.write_bytes(yaml.safe_dump(TINY).encode().replace(b"name: tiny", b"name: caf\xe9"))
    line = _one_line_refusal(_qsls("run", cfg, cwd=tmp_path))
    assert "not UTF-8" in line and "0xe9" in line and "save the config as UTF-8" in line
    line = _one_line_refusal(_qsls("synth", "--config", cfg, "--out", tmp_path / "s",
                                   cwd=tmp_path))  # fmt: skip
    assert "not UTF-8" in line


def test_a_yaml_alias_bomb_is_refused_at_once(tmp_path):
    """Nine levels of nine aliases: 1 kB that expands to 387 million values."""
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    for k in range(1, 10):
        lines.append(f"a{k}: &a{k} [{', '.join([f'*a{k - 1}'] * 9)}]")
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("\n".join(lines) + "\nname: bomb\nflights: *a9\n")
    assert len(bomb.read_bytes()) < 1100
    line = _one_line_refusal(_qsls("run", bomb, cwd=tmp_path, timeout=60))
    assert "expands to more than" in line


@pytest.mark.parametrize(
    ("change", "expect"),
    [
        ({"name": "../../escaped"}, "the run name must be a plain folder name"),
        ({"name": "a\nb"}, "the run name must be a plain folder name"),
        ({"flights": [{"name": "f\n1", "simulate": {"seed": 1}}]}, "a flight name"),
    ],
    ids=["run-name-traversal", "run-name-newline", "flight-name-newline"],
)
def test_names_that_are_not_plain_folder_names_are_refused(tmp_path, change, expect):
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    cfg = work / "bad.yaml"
    cfg.write_text(yaml.safe_dump({**TINY, **change}))
    before = sorted(tmp_path.rglob("*"))
    line = _one_line_refusal(_qsls("run", cfg, cwd=work))
    assert expect in line
    assert sorted(tmp_path.rglob("*")) == before  # nothing written, inside runs/ or out of it


@pytest.mark.parametrize("name", ["run_state.json", "run.json"])
def test_a_state_file_that_is_a_folder_is_one_line(tmp_path, name):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    root = tmp_path / "run"
    (root / name).mkdir(parents=True)
    (root / name / "keep.txt").write_text("the user's")
    (root / ("run.json" if name != "run.json" else "run_state.json")).write_text("{}")
    line = _one_line_refusal(_qsls("run", cfg, "--out", root, cwd=tmp_path))
    assert f"{name} is not a file qsls wrote" in line
    assert (root / name / "keep.txt").read_text() == "the user's"


def test_a_binary_run_state_is_read_as_no_state(tmp_path):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    root = tmp_path / "run"
    root.mkdir()
    (root / "run_state.json").write_bytes(bytes(range(256)) * 4)
    proc = _qsls("run", cfg, "--out", root, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (root / "simulate" / "f1" / "manifest.json").is_file()
    (root / "run.json").write_bytes(b"\xff\xfe\x00binary")
    line = _one_line_refusal(_qsls("report", root, "--out", tmp_path / "rep", cwd=tmp_path))
    assert "run.json: not the JSON file qsls writes" in line


def test_a_flight_both_simulated_and_logged_is_refused(tmp_path):
    flight = {"name": "f1", "simulate": {"seed": 1}, "sources": ["missing.bag"]}
    cfg = tmp_path / "both.yaml"
    cfg.write_text(yaml.safe_dump({**TINY, "flights": [flight]}))
    line = _one_line_refusal(_qsls("run", cfg, cwd=tmp_path))
    assert "flight 'f1' has both simulate: and sources" in line


@pytest.mark.parametrize(
    "change",
    [{"stages": ["simulate", "ingest", "fit", "synth", "evaluate"]}, {"evaluate": {}}],
    ids=["stages", "section"],
)
def test_evaluate_without_heldout_flights_is_refused(tmp_path, change):
    data = {**TINY, "stages": None, "synth": {"T": 5}, **change}
    data["evaluate"] = {"smooth_s": 0.5} if "stages" in change else data.get("evaluate")
    data = {k: v for k, v in data.items() if v is not None}
    cfg = tmp_path / "noheld.yaml"
    cfg.write_text(yaml.safe_dump(data))
    line = _one_line_refusal(_qsls("run", cfg, cwd=tmp_path))
    assert "nothing to evaluate" in line and "held-out flight" in line
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
def test_an_infeasible_synth_names_its_stage_and_the_report_shows_what_finished(tmp_path):
    data = {**TINY, "stages": ["simulate", "ingest", "fit", "synth", "report"],
            "synth": {"T": 5, "S": 1.5, "controllers": "single"}, "report": True}  # fmt: skip
    cfg = tmp_path / "infeasible.yaml"
    cfg.write_text(yaml.safe_dump(data))
    proc = _qsls("run", cfg, "--out", tmp_path / "run", cwd=tmp_path, timeout=300)
    assert proc.returncode == 3 and "Traceback" not in proc.stderr, proc.stderr
    (line,) = [ln for ln in proc.stderr.splitlines() if ln.startswith("error")]
    assert line.startswith("error: stage synth failed: ")
    report = tmp_path / "run" / "report" / "index.html"
    assert f"the report of the stages that finished: {report}" in line
    assert report.is_file() and (tmp_path / "run" / "fit" / "manifest.json").is_file()
