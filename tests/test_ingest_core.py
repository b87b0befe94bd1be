"""The pure ingest core: ``flight_from_streams`` on streams held in memory makes the flight
the ``qsls ingest`` stage makes of a real bag written from those streams (rosbags' writer,
read back by the bag readers): the same table, column for column and bit for bit, and the
same manifest results but for where the streams came from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from qsls.pipeline.ingest.assemble import flight_from_streams
from qsls.pipeline.ingest.flight import FLIGHT_FILE
from qsls.pipeline.ingest.sources.base import Trajectory
from qsls.pipeline.ingest.sources.messages import OdometryStream, PoseStream
from qsls.pipeline.ingest.sources.write import write_bag
from qsls.pipeline.ingest.stage import IngestOptions, ingest
from tests.bagfixtures import make_flight


def as_trajectory(s: OdometryStream | PoseStream) -> Trajectory:
    """The :class:`Trajectory` a reader returns for ``s``'s topic once written (copies: the
    ingest core normalizes quaternions in place), without a bag: streams in memory for
    :func:`qsls.pipeline.ingest.assemble.flight_from_streams`. A TF stream is its
    transforms; covariances all zero are none (ROS: unknown), as the readers say."""
    n = len(s)
    if isinstance(s, OdometryStream):
        velocity: np.ndarray | None = np.array(s.linear_velocity, dtype=float)
        cov = [c for c in (s.pose_covariance, s.twist_covariance) if c is not None]
        recorded = any(np.any(np.asarray(c) != 0) for c in cov)
        diag = [
            np.zeros((n, 6)) if c is None else np.asarray(c, dtype=float)[:, ::7].copy()
            for c in (s.pose_covariance, s.twist_covariance)
        ]
        pose_var, twist_var = (diag[0], diag[1]) if recorded else (None, None)
    else:
        velocity = pose_var = twist_var = None
    return Trajectory(
        name=s.topic,
        msgtype=s.msgtype,
        header_ns=np.array(s.header_ns, dtype=np.int64),
        log_ns=np.array(s.log_ns, dtype=np.int64),
        position=np.array(s.position, dtype=float),
        orientation=np.array(s.orientation, dtype=float),
        velocity=velocity,
        frame_id=s.frame_id,
        child_frame_id=s.child_frame_id,
        decoder="memory",
        pose_var=pose_var,
        twist_var=twist_var,
    )


def _without_origin(results: dict) -> dict:
    streams = {
        role: {k: v for k, v in s.items() if k not in ("source", "decoder")}
        for role, s in results["streams"].items()
    }
    return {**results, "streams": streams}


@pytest.mark.parametrize("fmt", ["ros1", "ros2-mcap"])
def test_core_on_streams_in_memory_is_the_stage_on_their_bag(fmt: str, tmp_path: Path) -> None:
    import numpy as np

    f = make_flight(duration=10.0, seed=5)
    n = len(f.vio)
    cov = np.zeros((n, 36))
    cov[:, ::7] = np.linspace(1e-4, 2e-4, n)[:, None]  # the covariance columns ride along
    vio = OdometryStream(
        f.vio.topic, f.vio.header_ns, f.vio.log_ns, f.vio.position, f.vio.orientation,
        f.vio.linear_velocity, None, f.vio.frame_id, f.vio.child_frame_id, cov, cov,
    )  # fmt: skip
    bag = write_bag(tmp_path / ("f.bag" if fmt == "ros1" else "f"), [vio, f.truth], fmt)
    o = IngestOptions(export_tum=True)
    res = ingest([bag], o, tmp_path / "out")
    staged = pq.read_table(tmp_path / "out" / FLIGHT_FILE)

    core = flight_from_streams(as_trajectory(vio), as_trajectory(f.truth), o)

    assert core.table.column_names == staged.column_names
    assert "var_px" in core.table.column_names and core.samples == res.samples > 50
    for name in staged.column_names:
        a, b = core.table[name].to_numpy(), staged[name].to_numpy()
        assert a.tobytes() == b.tobytes(), name
    from qsls.pipeline.core.artifacts import read_manifest

    manifest = read_manifest(tmp_path / "out")["results"]
    assert _without_origin(core.results) == _without_origin(manifest)
    assert abs(core.results["time_offset_s"] - f.offset_s) < 0.01  # a number that could be wrong
    assert set(core.tracks) == {"vio", "truth"}
