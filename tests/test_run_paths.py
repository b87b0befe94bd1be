"""A config named in another way (relative, absolute, from another working directory, through a
symbolic link) gives the same ``run.json`` record (issue 37): a run with nothing to do then
rewrites neither it nor the report, which follows ``run.json``."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml

from qsls.pipeline.core.artifacts import dump_json
from qsls.pipeline.run.runner import load_run_config, run_info
from tests.test_run_cache import SMALL


def test_run_record_does_not_depend_on_how_the_config_is_named(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "cfg").mkdir()
    (tmp_path / "other").mkdir()
    cfg = tmp_path / "cfg" / "small.yaml"
    cfg.write_text(yaml.safe_dump(SMALL, sort_keys=False))
    os.symlink(tmp_path / "cfg", tmp_path / "link")
    config = load_run_config(cfg)
    records = []
    for cwd, spelled in (
        (tmp_path, Path("cfg/small.yaml")),
        (tmp_path, cfg),
        (tmp_path / "other", Path("../cfg/./small.yaml")),
        (tmp_path, Path("link/small.yaml")),
    ):
        monkeypatch.chdir(cwd)
        records.append(dump_json(run_info(config, spelled, ["ingest", "fit"])))
    assert len(set(records)) == 1
    assert f'"config_path": "{cfg.resolve().as_posix()}"' in records[0]
