"""qsls's JSON files are JSON (issue 50): a non-finite number is written ``null``, never
``NaN``/``Infinity`` (Python's extension, which other readers refuse), and read back as what
it meant (docs/conventions.md#json); a calibration summary that was corrupted, truncated or
edited (even keeping its size and time) is refused by the report in one line."""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.core.artifacts import dump_json, json_number, read_json
from qsls.pipeline.core.errors import InputError


def test_non_finite_numbers_are_written_null_and_the_file_is_strict_json(tmp_path):
    import numpy as np

    doc = {"a": math.nan, "b": [1.5, math.inf, -math.inf], "c": {"d": np.float64("nan")},
           "e": np.array([1.0, np.inf]), "f": 2, "g": "NaN"}  # fmt: skip
    text = dump_json(doc)
    assert "NaN" not in text.replace('"NaN"', "") and "Infinity" not in text
    strict = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))
    assert strict == {"a": None, "b": [1.5, None, None], "c": {"d": None}, "e": [1.0, None],
                      "f": 2, "g": "NaN"}  # fmt: skip
    assert math.isnan(json_number(strict["a"]))
    assert json_number(strict["b"][1], math.inf) == math.inf
    assert json_number(strict["b"][0], math.inf) == 1.5


def test_read_json_refuses_a_corrupt_or_truncated_file_in_one_line(tmp_path):
    f = tmp_path / "x.json"
    f.write_text(dump_json({"certificates": [{"a": 1}]}))
    assert read_json(f) == {"certificates": [{"a": 1}]}
    f.write_bytes(f.read_bytes()[:-9])
    with pytest.raises(InputError, match=r"x.json: not valid JSON .*; rerun it"):
        read_json(f, "rerun it")
    f.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(InputError, match="not valid JSON"):
        read_json(f)
    old = tmp_path / "old.json"  # written by an earlier version: still read
    old.write_text('{"x": NaN, "y": Infinity}')
    assert math.isinf(read_json(old)["y"])


@pytest.fixture(scope="module")
def quickstart_run(quickstart_session, tmp_path_factory):
    """A copy of the session's quickstart run (conftest), the tests corrupt their own."""
    src = quickstart_session[0] / "runs" / "quickstart"
    dst = tmp_path_factory.mktemp("qs_json") / "quickstart"
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("report"))
    return dst


def test_the_quickstarts_json_files_are_strict_json(quickstart_session):
    run = quickstart_session[0] / "runs" / "quickstart"
    files = sorted(run.rglob("*.json"))
    assert len(files) > 10
    for f in files:
        json.loads(f.read_text(), parse_constant=lambda c, f=f: pytest.fail(f"{f}: {c}"))
    evaluation = json.loads((run / "fly" / "evaluation.json").read_text())
    assert "null" in (run / "fly" / "evaluation.json").read_text() and evaluation


def _report(run: Path, out: Path) -> str:
    res = CliRunner().invoke(app, ["report", str(run), "--out", str(out), "--force"])
    assert res.exit_code == 2, (res.exit_code, res.output, res.exception)
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    return lines[0]


@pytest.mark.parametrize("damage", ["flipped", "truncated", "same-size-and-time"])
def test_a_damaged_calibration_summary_is_one_line_from_the_report(quickstart_run, tmp_path,
                                                                   damage):  # fmt: skip
    run = tmp_path / "run"
    shutil.copytree(quickstart_run, run)
    f = run / "calibrate" / "calibration.json"
    raw = f.read_bytes()
    st = f.stat()
    if damage == "flipped":
        f.write_bytes(raw[:40] + b"\x00\xff{" + raw[43:])
    elif damage == "truncated":
        f.write_bytes(raw[: len(raw) // 2])
    else:  # valid JSON, same size and mtime: only the bytes' hash tells
        edited = raw.replace(b'"certified"', b'"certifieD"', 1)
        assert edited != raw and len(edited) == len(raw)
        f.write_bytes(edited)
        os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns))
        assert (f.stat().st_size, f.stat().st_mtime_ns) == (st.st_size, st.st_mtime_ns)
    line = _report(run, tmp_path / "report")
    assert "calibration.json" in line and "--from calibrate" in line
    assert not (tmp_path / "report").exists()
