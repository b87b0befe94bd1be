"""Stage files damaged after their stage wrote them (issue 50): a corrupt, truncated or
edited ``training_states.parquet`` is one line from calibrate and fly (not pyarrow's
traceback, not a silent read of changed bytes); a tick log with a NaN in ``x``, ``y`` or ``r``
is refused when read."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.ticks import TickLog
from qsls.pipeline.errormodel.model import TRAINING_FILE, load_training_states


@pytest.fixture(scope="module")
def run(quickstart_session) -> Path:
    return quickstart_session[0] / "runs" / "quickstart"


def _damage(path: Path, how: str) -> None:
    raw = path.read_bytes()
    mid = len(raw) // 2
    if how == "truncated":
        path.write_bytes(raw[:mid])
    elif how == "footer":
        path.write_bytes(raw[:-40] + b"\x07" * 32 + raw[-8:])
    else:  # bytes in the middle: pyarrow may read it, only the manifest's hash tells
        path.write_bytes(raw[:mid] + bytes(b ^ 0x5A for b in raw[mid : mid + 16]) + raw[mid + 16 :])


@pytest.mark.parametrize("how", ["truncated", "footer", "middle"])
def test_a_damaged_training_states_file_is_one_line_from_fly_and_calibrate(run, tmp_path, how):
    fit = tmp_path / "fit"
    shutil.copytree(run / "fit", fit)
    _damage(fit / TRAINING_FILE, how)
    with pytest.raises(InputError, match=r"training_states.parquet: .*qsls fit"):
        load_training_states(fit)
    for args in (
        ["fly", "--model", fit, "--controller", run / "synth" / "pd", "--seeds", "5",
         "--duration", "3"],
        ["calibrate", "--model", fit, "--controllers", run / "synth", "--only", "l1_robust",
         "--flights", "2", "--validation", "0", "--duration", "3"],
    ):  # fmt: skip
        out = tmp_path / f"out_{args[0]}"
        res = CliRunner().invoke(app, [*map(str, args), "--out", str(out)])
        lines = [ln for ln in res.output.splitlines() if ln.startswith("error: ")]
        assert res.exit_code == 2 and len(lines) == 1, (res.output, res.exception)
        assert "Traceback" not in res.output
        assert "training_states.parquet" in lines[0] and "qsls fit" in lines[0]
        assert not out.exists()


def test_training_states_without_a_manifest_still_refuses_unreadable_bytes(run, tmp_path):
    fit = tmp_path / "fit"
    shutil.copytree(run / "fit", fit)
    (fit / "manifest.json").unlink()
    (fit / TRAINING_FILE).write_bytes((fit / TRAINING_FILE).read_bytes()[:100])
    with pytest.raises(InputError, match="not a readable parquet file"):
        load_training_states(fit)


@pytest.mark.parametrize("column", ["x_px", "y_vz", "r_py"])
@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_a_tick_log_with_a_non_finite_state_measurement_or_reference_is_refused(
    run, tmp_path, column, value
):
    src = next((run / "calibrate" / "flights").glob("calibration_*/ticks.parquet"))
    assert TickLog.read(src).t.size > 10  # the real log reads
    df = pd.read_parquet(src)
    df.loc[7, column] = value
    bad = tmp_path / "ticks.parquet"
    df.to_parquet(bad)
    with pytest.raises(InputError, match=rf"{column} is {value} at tick 7: not a flown value"):
        TickLog.read(bad)
