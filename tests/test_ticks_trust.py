"""A tick log is trusted for nothing it does not prove (issue 50, item 3): a malformed, short,
non-finite or time-scrambled ``ticks.parquet`` is refused in one line, never checked; the
controller that wrote it is kept in its metadata; its ticks must be the controller's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from qsls.pipeline.core.artifacts import parquet_bytes
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.ticks import MIN_TICKS, TickLog


def flight(n: int = 40, dt: float = 0.1) -> TickLog:
    rng = np.random.default_rng(3)
    t = np.arange(n) * dt
    x = rng.normal(size=(n, 6))
    return TickLog(t, x, x + 0.01, rng.normal(size=(n, 3)), x * 0, rng.normal(size=(n, 3)),
                   controller="l1_robust", controller_sha256="ab" * 32)  # fmt: skip


def written(tmp_path: Path, df: pd.DataFrame, name: str = "ticks.parquet") -> Path:
    p = tmp_path / name
    p.write_bytes(parquet_bytes(df))
    return p


def test_identity_round_trips_through_the_file(tmp_path: Path) -> None:
    log = flight()
    back = TickLog.read(written(tmp_path, log.frame()))
    assert back.controller == "l1_robust" and back.controller_sha256 == "ab" * 32
    assert np.array_equal(back.u, log.u) and np.array_equal(back.t, log.t)
    assert back.off_rate(0.1) == ""
    assert "0.2 s apart" in TickLog(*(a[::2] for a in (log.t, log.x, log.y, log.u, log.ref,
                                                       log.uff))).off_rate(0.1)  # fmt: skip


@pytest.mark.parametrize(
    ("edit", "said"),
    [
        (lambda df: df.assign(u_thrust=np.where(df.index == 7, np.nan, df["u_thrust"])),
         "u_thrust is nan at tick 7"),
        (lambda df: df.assign(t=df["t"].to_numpy()[::-1].copy()), "t does not increase at tick 1"),
        (lambda df: df.assign(t=np.where(df.index == 5, 0.3, df["t"])), "t does not increase"),
        (lambda df: df.iloc[:1], "1 ticks"),
        (lambda df: df.iloc[:0], "0 ticks"),
        (lambda df: df.drop(columns=["uff_roll", "x_pz"]), "no column x_pz, uff_roll"),
        (lambda df: df.assign(y_vx=np.where(df.index == 2, np.inf, df["y_vx"])), "y_vx is inf"),
    ],
)  # fmt: skip
def test_a_malformed_log_is_refused_in_one_line(tmp_path: Path, edit, said: str) -> None:
    p = written(tmp_path, edit(flight().frame()))
    with pytest.raises(InputError) as e:
        TickLog.read(p)
    assert said in str(e.value) and "\n" not in str(e.value)


def test_a_truncated_or_foreign_file_is_refused(tmp_path: Path) -> None:
    data = parquet_bytes(flight().frame())
    cut = tmp_path / "cut.parquet"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="not a readable tick log"):
        TickLog.read(cut)
    text = tmp_path / "text.parquet"
    text.write_text("t,x_px\n0,1\n")
    with pytest.raises(InputError, match="not a readable tick log"):
        TickLog.read(text)
    assert MIN_TICKS == 10
