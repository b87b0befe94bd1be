"""mavros bags as recorded flights (docs/vehicle.md#what-to-log): the PX4 stand-in written as
a mavros user records it (``log.format: mavros``), ingested with ``--mass --hover-thrust``,
gives the simulator's own tick log back, and the replay proof tells the candidate's flight
from a PD's."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.core.plant import GRAVITY
from qsls.pipeline.core.ticks import TickLog
from qsls.pipeline.evaluate.flownby import flown_by
from qsls.pipeline.ingest.options import IngestOptions
from qsls.pipeline.ingest.sources.mavros import read_bag_commands, read_bag_setpoints
from qsls.pipeline.ingest.sources.messages import AttitudeTargetStream, PositionTargetStream
from qsls.pipeline.ingest.sources.write import write_bag
from qsls.pipeline.ingest.stage import ingest
from qsls.pipeline.sim.mavroslog import COMMANDS, REFERENCE, mavros_log
from qsls.pipeline.sim.options import SimOptions
from qsls.pipeline.sim.px4log import Identity
from qsls.pipeline.sim.simulate import simulate
from tests.controllerfixtures import synthesized

MASS = 0.256
HOVER = 0.5
runner = CliRunner()


def _options(kind: str) -> SimOptions:
    """A stand-in flight as a mavros bag: the PX4 interface with latency, jitter and drops;
    the motion capture noiseless at 200 Hz (on the physics grid: the truth's positions at the
    ticks are exact)."""
    return SimOptions.model_validate(
        {
            "duration": 8,
            "controller": {"kind": kind},
            "log": {"format": "mavros"},
            "px4": {
                "interface": "px4", "estimator_latency_s": 0.015, "estimator_jitter_s": 0.004,
                "estimator_drop": 0.05, "mocap_latency_s": 0.004, "mocap_jitter_s": 0.002,
                "mocap_drop": 0.01,
            },
            "mocap": {"rate_hz": 200, "position_noise": 0.0, "attitude_noise": 0.0},
        }
    )  # fmt: skip


@pytest.fixture(scope="module")
def controller(tmp_path_factory):
    """A certified robust L1 controller (T = 8), written as ``qsls synth`` writes one."""
    return synthesized(T=8, calibrated=tmp_path_factory.mktemp("mavros")).folder


@pytest.fixture(scope="module")
def flights(controller, tmp_path_factory):
    """The candidate's flight and a PD's, each written as a mavros bag."""
    d = tmp_path_factory.mktemp("flights")
    return {
        name: simulate(_options(kind), d / name)
        for name, kind in (("candidate", str(controller)), ("pd", "pd"))
    }


def _ingest_cli(bag: Path, out: Path, *extra: str):
    return runner.invoke(app, ["ingest", str(bag), "--mass", str(MASS), *extra, "--out", str(out)])


def _refusal(res) -> str:
    text = res.output.strip()
    assert res.exit_code != 0 and text.startswith("error: ") and "\n" not in text, text
    return text


def test_the_bag_ingests_to_the_simulators_own_tick_log(flights, tmp_path):
    """t exact; y and the reference to float64 (the bag's precision); u to the thrust's
    float32 (AttitudeTarget.thrust); x exact in position, its velocity the positions'
    central differences."""
    sim = flights["candidate"]
    assert sim.bag.name == "flight.bag"
    res = _ingest_cli(sim.bag, tmp_path / "c", "--hover-thrust", str(HOVER))
    assert res.exit_code == 0, res.output
    want, got = TickLog.read(sim.out), TickLog.read(tmp_path / "c")
    assert len(got.t) == len(want.t) > 60
    assert np.array_equal(got.t, want.t)
    assert np.abs(got.y - want.y).max() <= 1e-12
    assert np.abs(got.ref - want.ref).max() <= 1e-12
    assert np.abs(got.uff - want.uff).max() <= 1e-12
    du = np.abs(got.u - want.u).max(axis=0)
    assert du[:2].max() <= 2e-8 and du[2] <= 1e-7 * MASS * GRAVITY, du  # float32 thrust
    assert np.abs(got.x[:, :3] - want.x[:, :3]).max() <= 1e-12
    assert np.abs(got.x[:, 3:] - want.x[:, 3:]).max() <= 1e-3
    facts = json.loads((tmp_path / "c" / "manifest.json").read_text())["results"]["ticks"]
    assert facts["hover_source"] == "given" and facts["hover_thrust"] == HOVER
    assert facts["commands_topic"] == COMMANDS and facts["reference_topic"] == REFERENCE
    assert facts["stamps"] == {} and facts["ticks"] == len(want.t)
    truth = json.loads((sim.out / "truth.json").read_text())
    assert truth["format"] == "mavros" and truth["px4"]["estimator"]["dropped"] > 0


def test_flown_by_tells_the_candidate_from_a_pd(flights, controller, tmp_path):
    logs = {}
    for name, sim in flights.items():
        ingest([sim.bag], IngestOptions(mass=MASS, hover_thrust=HOVER), tmp_path / name)
        logs[name] = TickLog.read(tmp_path / name)
    own = flown_by(logs["candidate"], controller, MASS)
    assert own.flown and own.max_difference < 1e-6, own
    other = flown_by(logs["pd"], controller, MASS)
    assert not other.flown and other.tick is not None and "replayed through" in other.reason


@pytest.mark.parametrize("fmt", ["ros2-sqlite", "ros2-mcap", "mcap"])
def test_every_bag_format_reads_the_same_commands(flights, tmp_path, fmt):
    """mavros' types through rosbags' ROS2 typestore (rosbag2) and the file's own schemas
    (MCAP): the same setpoints as the ROS1 bag's."""
    sim = flights["candidate"]
    streams, _ = mavros_log(sim.flight, _options("pd"), 0, Identity("x"))
    bag = write_bag(tmp_path / ("b.mcap" if fmt == "mcap" else "b"), streams, fmt)
    for read, topic in ((read_bag_commands, COMMANDS), (read_bag_setpoints, REFERENCE)):
        a, b = read(sim.bag, topic), read(bag, topic)
        for field in a.__dataclass_fields__:
            va, vb = getattr(a, field), getattr(b, field)
            if isinstance(va, np.ndarray):
                assert np.array_equal(va, vb, equal_nan=True), (fmt, field)
            else:
                assert va == vb, (fmt, field)


def test_a_bag_needs_the_hover_thrust_and_the_commands(flights, tmp_path):
    sim = flights["candidate"]
    text = _refusal(_ingest_cli(sim.bag, tmp_path / "a"))
    assert "--hover-thrust" in text and "states no hover thrust" in text
    streams, _ = mavros_log(sim.flight, _options("pd"), 0, Identity("x"))
    bare = write_bag(
        tmp_path / "bare.bag",
        [s for s in streams if not isinstance(s, AttitudeTargetStream | PositionTargetStream)],
        "ros1",
    )
    text = _refusal(_ingest_cli(bare, tmp_path / "b", "--hover-thrust", str(HOVER)))
    assert "/mavros/setpoint_raw/target_attitude" in text and "/vio/odometry (Odometry)" in text
    assert "record the controller's attitude setpoints" in text
    text = _refusal(
        _ingest_cli(sim.bag, tmp_path / "c", "--hover-thrust", "0.5", "--commands-topic", "/x")
    )
    assert "no commands topic (/x)" in text
    text = _refusal(
        _ingest_cli(sim.bag, tmp_path / "d", "--hover-thrust", "0.5", "--commands-topic", REFERENCE)
    )
    assert "PositionTarget, not mavros_msgs/msg/AttitudeTarget" in text
    assert not any((tmp_path / n).exists() for n in "abcd")
