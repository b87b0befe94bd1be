"""The VIO's odometry covariances kept at ingest (issue 33) and its position NEES.

A bag whose Odometry messages carry known covariances (diagonals linear in time, so the
resampling reproduces them exactly; off-diagonal terms that must not leak in) is read back
through ``qsls ingest`` in three formats and both decoders: ``flight.parquet`` gains the
``var_*`` columns with those values. The NEES of the flight equals a hand computation from
its error columns, variances and the manifest's alignment.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.evaluate.nees import CHI2_3_95, position_nees
from qsls.pipeline.evaluate.stage import load_flights, vio_nees
from qsls.pipeline.ingest.flight import VAR_COLS, read_flight
from qsls.pipeline.ingest.sources.write import write_bag
from tests.bagfixtures import T0_NS, make_flight

runner = CliRunner()

SLOPE = np.array([1, 2, 0, 3, 1, 2, 4, 0, 1, 2, 3, 1]) * 1e-6
BASE = np.array([4, 5, 6, 100, 200, 300, 1e4, 2e4, 3e4, 400, 500, 600]) * 1e-6


def diagonals(t_s: np.ndarray) -> np.ndarray:
    """The recorded diagonals ``(n, 12)`` at times ``t_s``: pose, then twist."""
    return BASE + np.outer(t_s, SLOPE)


def with_covariances(vio):
    t = (vio.header_ns - T0_NS) * 1e-9
    d = diagonals(t)
    full = np.full((len(t), 2, 6, 6), 1e-7)  # off-diagonal terms, not to be read
    idx = np.arange(6)
    full[:, 0, idx, idx] = d[:, :6]
    full[:, 1, idx, idx] = d[:, 6:]
    return replace(
        vio,
        pose_covariance=full[:, 0].reshape(-1, 36),
        twist_covariance=full[:, 1].reshape(-1, 36),
    )


@pytest.fixture(scope="module")
def flight():
    return make_flight(duration=20.0, vio_hz=100.0, truth_hz=200.0, dropouts=())


@pytest.mark.parametrize(
    ("fmt", "name", "decoder"),
    [
        ("ros1", "c.bag", "fast"),
        ("ros2-sqlite", "c_sqlite", "fast"),
        ("mcap", "c.mcap", "fast"),
        ("ros1", "d.bag", "deserializer"),
    ],
)
def test_covariance_diagonals_reach_the_flight_table(
    flight, tmp_path: Path, fmt: str, name: str, decoder: str
) -> None:
    bag = write_bag(tmp_path / name, [with_covariances(flight.vio), flight.truth], fmt)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"decoder: {decoder}\n")
    out = tmp_path / "out"
    res = runner.invoke(app, ["ingest", str(bag), "--config", str(cfg), "--out", str(out)])
    assert res.exit_code == 0, res.output
    df = read_flight(out)
    assert list(df.columns[-12:]) == list(VAR_COLS)
    want = diagonals((df["stamp_ns"].to_numpy() - T0_NS) * 1e-9)
    np.testing.assert_allclose(df[list(VAR_COLS)].to_numpy(), want, rtol=1e-12, atol=0)
    m = json.loads((out / "manifest.json").read_text())
    assert m["results"]["covariance_columns"] == list(VAR_COLS)
    want_decoder = "numpy" if decoder == "fast" else "deserializer"
    assert m["results"]["streams"]["vio"]["decoder"] == want_decoder


def test_zero_covariances_add_no_columns(flight, tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "z.bag", [flight.vio, flight.truth], "ros1")
    out = tmp_path / "out"
    assert runner.invoke(app, ["ingest", str(bag), "--out", str(out)]).exit_code == 0
    assert not any(c.startswith("var_") for c in read_flight(out).columns)
    assert "covariance_columns" not in json.loads((out / "manifest.json").read_text())["results"]


def test_position_nees_by_hand(flight, tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "n.bag", [with_covariances(flight.vio), flight.truth], "ros1")
    out = tmp_path / "out"
    assert runner.invoke(app, ["ingest", str(bag), "--out", str(out)]).exit_code == 0
    df = read_flight(out)
    rot = np.array(
        json.loads((out / "manifest.json").read_text())["results"]["alignment"]["rotation"]
    )
    assert abs(np.degrees(np.arctan2(rot[1, 0], rot[0, 0])) - 37.0) < 0.5  # the fixture's yaw
    hand = []
    for _, row in df.iterrows():
        e = np.array([row["e_px"], row["e_py"], row["e_pz"]])
        e_vio = rot.T @ e  # the error in the VIO's world frame, where its covariance is
        var = np.array([row["var_px"], row["var_py"], row["var_pz"]])
        hand.append(sum(e_vio[i] ** 2 / var[i] for i in range(3)))
    nees = position_nees(df, rot)
    assert nees is not None
    np.testing.assert_allclose(nees, hand, rtol=1e-12)
    (got,) = vio_nees([out], load_flights([out]))
    assert got.samples == len(df)
    assert got.mean == pytest.approx(float(np.mean(hand)), rel=1e-12)
    assert got.share_above_95 == pytest.approx(float(np.mean(np.array(hand) > CHI2_3_95)))
    assert "consistent: 3" in got.text()


def test_covariances_that_start_later_are_kept(
    flight, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """sqlite3 reads each range of rows lean when its covariances are all zero, with their
    diagonals otherwise: a VIO that reports covariances only after 10 s keeps them."""
    from qsls.pipeline.ingest.sources.rosbag2 import sqlite
    from qsls.pipeline.ingest.stage import IngestOptions, ingest

    vio = with_covariances(flight.vio)
    late = (vio.header_ns - T0_NS) * 1e-9 >= 10.0
    vio = replace(
        vio,
        pose_covariance=vio.pose_covariance * late[:, None],
        twist_covariance=vio.twist_covariance * late[:, None],
    )
    bag = write_bag(tmp_path / "late", [vio, flight.truth], "ros2-sqlite")
    monkeypatch.setattr(sqlite, "_QUERY_BYTES", 20_000)  # many ranges, lean ones first
    ingest([bag], IngestOptions(), tmp_path / "out")
    df = read_flight(tmp_path / "out")
    t = (df["stamp_ns"].to_numpy() - T0_NS) * 1e-9
    got = df[list(VAR_COLS)].to_numpy()
    assert np.all(got[t < 9.9] == 0)
    np.testing.assert_allclose(got[t > 10.1], diagonals(t[t > 10.1]), rtol=1e-12, atol=0)
