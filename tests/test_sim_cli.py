"""qsls simulate end to end: bags in four formats, truth files, ingest recovery, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.ingest.sources.bags import BagSource
from qsls.pipeline.ingest.sources.write import FORMATS
from qsls.pipeline.sim.simulate import SimOptions, bag_name, simulate

runner = CliRunner()
E_COLS = [f"e_{s}" for s in ("px", "py", "pz", "vx", "vy", "vz")]
X_COLS = [c.replace("e_", "x_") for c in E_COLS]

# short flights: 1 s hold, 1 s climb, 1 s approach, then a bit of circle
SHORT = {"reference": {"hold_s": 0.5, "takeoff_s": 1.0, "approach_s": 1.0}, "duration": 4.0}


def _rz(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _rot(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q.T
    r = np.empty((len(q), 3, 3))
    r[:, 0] = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], 1)
    r[:, 1] = np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], 1)
    r[:, 2] = np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], 1)
    return r


# per format, also another VIO rate (off the physics grid) and mocap message type
VARIANTS = {
    "ros1": {},
    "ros2-sqlite": {"vio": {"rate_hz": 30.0}, "mocap": {"rate_hz": 200.0}},
    "ros2-mcap": {"log": {"mocap_msgtype": "TransformStamped"}},
    "mcap": {"vio": {"rate_hz": 200.0}, "log": {"mocap_msgtype": "TransformStamped"}},
}


@pytest.mark.parametrize("fmt", FORMATS)
def test_formats_clocks_and_frames_round_trip(tmp_path: Path, fmt: str) -> None:
    from qsls.pipeline.core.config import merge

    data = merge({**SHORT, "log": {"format": fmt}, "seed": 5}, VARIANTS[fmt])
    opts = SimOptions.model_validate(data)
    res = simulate(opts, tmp_path / "sim")
    assert res.bag == tmp_path / "sim" / bag_name(fmt) and res.bag.exists()
    truth = json.loads((tmp_path / "sim" / "truth.json").read_text())
    manifest = json.loads((tmp_path / "sim" / "manifest.json").read_text())
    assert manifest["stage"] == "simulate" and manifest["results"]["bag"] == bag_name(fmt)
    errors = pd.read_parquet(tmp_path / "sim" / "errors.parquet")
    with BagSource(res.bag) as src:
        vio, mocap = src.read_many([(truth["vio_topic"], None), (truth["mocap_topic"], None)])
    assert len(vio) == truth["vio_messages"] == len(errors)
    assert len(mocap) == truth["mocap_messages"]
    assert vio.msgtype == "nav_msgs/msg/Odometry"
    assert mocap.msgtype == f"geometry_msgs/msg/{opts.log.mocap_msgtype}"
    vio_rate = 1e9 / np.median(np.diff(vio.header_ns))
    assert vio_rate == pytest.approx(opts.vio.rate_hz, rel=1e-3)
    assert len(vio) == pytest.approx(opts.vio.rate_hz * SHORT["duration"] + 1, abs=1)
    # VIO stamps are the errors' stamps (VIO clock), log time = stamp + delay
    np.testing.assert_array_equal(vio.header_ns, errors["stamp_ns"].to_numpy())
    lag = (vio.log_ns - vio.header_ns) / 1e9
    assert lag.min() >= opts.log.vio_delay_s - 1e-9
    # back to the mocap frame: p = Rz p_vio + t, v = Rz R_vio(q) twist == x + e
    yaw, t = truth["vio_frame"]["yaw_rad"], np.array(truth["vio_frame"]["translation"])
    y = errors[X_COLS].to_numpy() + errors[E_COLS].to_numpy()
    np.testing.assert_allclose(vio.position @ _rz(yaw).T + t, y[:, :3], atol=1e-9)
    v_vio = np.einsum("nij,nj->ni", _rot(vio.orientation), vio.velocity)
    np.testing.assert_allclose(v_vio @ _rz(yaw).T, y[:, 3:], atol=1e-9)
    # mocap: its clock + time_offset_s = VIO clock; millimetre noise around the truth
    traj = pd.read_parquet(tmp_path / "sim" / "trajectory.parquet")
    on_vio = mocap.header_ns + round(truth["time_offset_s"] * 1e9)
    p_true = np.column_stack(
        [np.interp(on_vio, traj["stamp_ns"], traj[c]) for c in ("x_px", "x_py", "x_pz")]
    )
    d = mocap.position - p_true
    assert 0.0005 < d.std() < 0.002 and np.abs(d).max() < 0.01
    rate = 1e9 / np.median(np.diff(mocap.header_ns))
    assert rate == pytest.approx(opts.mocap.rate_hz, rel=1e-3)


def _messages(bag: Path) -> list[tuple[str, int, bytes]]:
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        return [(c.topic, ts, bytes(raw)) for c, ts, raw in reader.messages()]


def test_same_seed_same_messages_other_seed_differs(tmp_path: Path) -> None:
    outs = []
    for name, seed in (("a", 11), ("b", 11), ("c", 12)):
        cfg = tmp_path / f"{name}.yaml"
        cfg.write_text(json.dumps({**SHORT, "seed": seed}))
        r = runner.invoke(app, ["simulate", "--config", str(cfg), "--out", str(tmp_path / name)])
        assert r.exit_code == 0, r.output
        outs.append(tmp_path / name)
    a, b, c = (_messages(o / "flight.bag") for o in outs)
    assert len(a) > 500 and a == b
    assert a != c
    for f in ("errors.parquet", "trajectory.parquet", "control.parquet", "truth.json"):
        assert (outs[0] / f).read_bytes() == (outs[1] / f).read_bytes()


def test_simulate_then_ingest_recovers_offset_yaw_and_errors(tmp_path: Path) -> None:
    """The figure-eight: on a circle alone a clock shift equals a rotation about its centre,
    which a position-based offset estimator cannot tell apart (see references.py)."""
    cfg = tmp_path / "sim.yaml"
    cfg.write_text(
        "simulate:\n  seed: 2\n  reference: {kind: figure8}\n"
        "  log: {time_offset_s: -0.113, vio_frame_yaw_deg: 47.0}\n"
    )
    sim = tmp_path / "sim"
    r = runner.invoke(app, ["simulate", "--config", str(cfg), "--out", str(sim)])
    assert r.exit_code == 0, r.output
    assert "tracking RMS" in r.output
    truth = json.loads((sim / "truth.json").read_text())
    assert truth["time_offset_s"] == -0.113 and not truth["crashed"]
    r = runner.invoke(app, ["ingest", str(sim / "flight.bag"), "--out", str(tmp_path / "ing")])
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "ing" / "manifest.json").read_text())["results"]
    assert abs(res["time_offset_s"] - truth["time_offset_s"]) < 0.005
    yaw_err = np.degrees(res["alignment"]["yaw_rad"] - truth["vio_frame"]["yaw_rad"])
    assert abs(yaw_err) < 0.5
    # the ingested e against the emulator's own e at the same stamps (VIO clock)
    flight = pd.read_parquet(tmp_path / "ing" / "flight.parquet")
    emu = pd.read_parquet(sim / "errors.parquet").set_index("stamp_ns")
    common = flight["stamp_ns"].isin(emu.index)
    assert common.mean() > 0.99
    got = flight.loc[common, E_COLS].to_numpy()
    want = emu.loc[flight.loc[common, "stamp_ns"], E_COLS].to_numpy()
    diff = (got - got.mean(0)) - (want - want.mean(0))
    pos, vel = diff[:, :3], diff[:, 3:]
    assert np.sqrt(np.mean(pos**2)) < 0.004 and np.abs(pos).max() < 0.015
    # velocity: the truth's velocity comes from differentiating mocap positions
    assert np.sqrt(np.mean(vel**2)) < 0.02
    assert np.corrcoef(got[:, 3], want[:, 3])[0, 1] > 0.9


def test_crash_is_a_flag_and_a_message_not_a_traceback(tmp_path: Path) -> None:
    cfg = tmp_path / "crash.yaml"
    cfg.write_text("controller: {kind: pd, pd: {kp: [2, 2, -6], kd: [2, 2, -3]}}\n")
    r = runner.invoke(app, ["simulate", "--config", str(cfg), "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    assert "crashed" in r.output and "Traceback" not in r.output
    truth = json.loads((tmp_path / "o" / "truth.json").read_text())
    assert truth["crashed"] is True and truth["crash_reason"]
    assert truth["crash_time_s"] < 5.0
    assert (tmp_path / "o" / "flight.bag").exists()


@pytest.mark.parametrize(
    "config,args,needle",
    [
        ("vio: {rate_hz: 100, noise_gian: 2}\n", [], "did you mean 'noise_gain'"),
        ("mocap: {rate_hz: -120}\n", [], "mocap.rate_hz"),
        ("vio: {rate_hz: -5}\n", [], "vio.rate_hz"),
        ("", ["--duration", "0.005"], "shorter than one control period"),
        ("", ["--duration", "-1"], "duration"),
        ("", ["--format", "ros3"], "log.format"),
        ("", ["--perception", "foggy"], "vio.perception"),
        ("", ["--controller", "no/such/folder"], "controller"),
    ],
)
def test_bad_input_is_one_line_and_leaves_nothing(tmp_path: Path, config, args, needle) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(config)
    out = tmp_path / "out"
    r = runner.invoke(app, ["simulate", "--config", str(cfg), "--out", str(out), *args])
    assert r.exit_code != 0
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), r.output
    assert needle in lines[0]
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


def test_example_config_is_the_defaults_and_runs_as_a_section(tmp_path: Path) -> None:
    from qsls.pipeline.core.config import load_options

    repo = Path(__file__).resolve().parents[1]
    opts = load_options(SimOptions, repo / "configs" / "simulate.yaml", section="simulate")
    assert opts == SimOptions()
    assert SimOptions().flight_duration() == pytest.approx(23.0)
