"""Decoded messages to a :class:`~qsls.pipeline.ingest.sources.base.Trajectory`, whatever
the bag format: message objects of a per-message deserializer (:func:`objects_to_arrays`,
:func:`trajectory_of`), or batches decoded at once by :mod:`.layout`, gathered topic by
topic into arrays allocated once (:class:`TopicColumns`). docs/ingest.md#formats."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.ingest.sources import layout
from qsls.pipeline.ingest.sources.base import TopicInfo, Trajectory
from qsls.pipeline.ingest.sources.msgtypes import ODOMETRY, TF


def norm_frame(name: str) -> str:
    return name.strip().lstrip("/")


def _pose_of(msg: Any, msgtype: str) -> tuple[Any, Any]:
    """(header, geometry_msgs/Pose-like object with position/orientation) of a message."""
    if msgtype == ODOMETRY or msgtype.endswith("PoseWithCovarianceStamped"):
        return msg.header, msg.pose.pose
    if msgtype.endswith("PoseStamped"):
        return msg.header, msg.pose
    raise ValueError(msgtype)


def _stamp(header: Any) -> int:
    st = header.stamp
    return int(st.sec) * 1_000_000_000 + int(getattr(st, "nanosec", getattr(st, "nsec", 0)))


def objects_to_arrays(
    msgs: list[Any], logs: list[int], msgtype: str, truth_frame: str | None, name: str
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, str, str, np.ndarray | None,
    np.ndarray | None,
]:  # fmt: skip
    """(header_ns, log_ns, pose (n,7), twist (n,6)|None, frame, child, pose covariance
    diagonal (n,6)|None, twist covariance diagonal (n,6)|None) from message objects."""
    rows: list[tuple[float, ...]] = []
    stamps: list[int] = []
    out_logs: list[int] = []
    twists: list[tuple[float, ...]] = []
    variances: list[np.ndarray] = []
    frame = child = ""
    if msgtype == TF or msgtype.endswith("TransformStamped"):
        if msgtype == TF:
            if not truth_frame:
                raise InputError(tf_frames_message(name, msgs))
            parent, want = (norm_frame(x) for x in truth_frame.strip().lstrip("/").split("/", 1))
        for msg, log in zip(msgs, logs, strict=True):
            transforms = msg.transforms if msgtype == TF else [msg]
            for tr in transforms:
                if msgtype == TF and (
                    norm_frame(tr.header.frame_id) != parent
                    or norm_frame(tr.child_frame_id) != want
                ):
                    continue
                t, r = tr.transform.translation, tr.transform.rotation
                rows.append((t.x, t.y, t.z, r.x, r.y, r.z, r.w))
                stamps.append(_stamp(tr.header))
                out_logs.append(log)
                frame, child = tr.header.frame_id, tr.child_frame_id
        if msgtype == TF and not rows:
            raise InputError(tf_frames_message(name, msgs, truth_frame))
    else:
        for msg, log in zip(msgs, logs, strict=True):
            header, pose = _pose_of(msg, msgtype)
            p, q = pose.position, pose.orientation
            rows.append((p.x, p.y, p.z, q.x, q.y, q.z, q.w))
            stamps.append(_stamp(header))
            out_logs.append(log)
            if msgtype == ODOMETRY:
                lin, ang = msg.twist.twist.linear, msg.twist.twist.angular
                twists.append((lin.x, lin.y, lin.z, ang.x, ang.y, ang.z))
                cov = (np.asarray(msg.pose.covariance), np.asarray(msg.twist.covariance))
                variances.append(np.concatenate([c.reshape(6, 6).diagonal() for c in cov]))
        if msgs:
            frame = msgs[0].header.frame_id
            child = getattr(msgs[0], "child_frame_id", "")
    pose = np.array(rows, dtype=float).reshape(-1, 7)
    twist = np.array(twists, dtype=float).reshape(-1, 6) if msgtype == ODOMETRY else None
    var = np.array(variances, dtype=float).reshape(-1, 12) if msgtype == ODOMETRY else None
    return (
        np.array(stamps, dtype=np.int64),
        np.array(out_logs, dtype=np.int64),
        pose,
        twist,
        frame,
        child,
        None if var is None else var[:, :6],
        None if var is None else var[:, 6:],
    )


def tf_frames_message(name: str, msgs: list[Any], asked: str | None = None) -> str:
    counts: dict[str, int] = {}
    for msg in msgs:
        for tr in msg.transforms:
            key = f"{norm_frame(tr.header.frame_id)}/{norm_frame(tr.child_frame_id)}"
            counts[key] = counts.get(key, 0) + 1
    pairs = ", ".join(f"{k} ({v})" for k, v in sorted(counts.items())) or "none"
    head = (
        f"topic {name} has no transform {asked}"
        if asked
        else f"topic {name} is a tf2_msgs/msg/TFMessage topic"
    )
    return f"{head}; pass --truth-frame PARENT/CHILD, one of: {pairs}"


def trajectory_of(
    name: str,
    msgtype: str,
    header_ns: np.ndarray,
    log_ns: np.ndarray,
    pose: np.ndarray,
    twist: np.ndarray | None,
    frame: str,
    child: str,
    decoder: str,
    pose_var: np.ndarray | None = None,
    twist_var: np.ndarray | None = None,
) -> Trajectory:
    known = [v for v in (pose_var, twist_var) if v is not None]
    recorded = any(np.any(v != 0) for v in known)  # all zero: unknown (ROS convention)
    return Trajectory(
        name=name,
        msgtype=msgtype,
        # contiguous: a column of ROS1's index would keep the whole index alive
        header_ns=np.ascontiguousarray(header_ns, dtype=np.int64),
        log_ns=np.ascontiguousarray(log_ns, dtype=np.int64),
        position=np.ascontiguousarray(pose[:, :3], dtype=float),
        orientation=np.ascontiguousarray(pose[:, 3:7], dtype=float),
        velocity=None if twist is None else np.ascontiguousarray(twist[:, :3], dtype=float),
        frame_id=frame,
        child_frame_id=child,
        decoder=decoder,
        pose_var=_variances(pose_var, len(header_ns)) if recorded else None,
        twist_var=_variances(twist_var, len(header_ns)) if recorded else None,
    )


def _variances(v: np.ndarray | None, n: int) -> np.ndarray:
    """A covariance diagonal ``(n, 6)``; zeros where the message had none."""
    return np.zeros((n, 6)) if v is None else np.ascontiguousarray(v, dtype=float)


class TopicColumns:
    """One topic's fields, filled batch by batch into arrays allocated once (for the count
    the bag's index or statistics give; doubled if more arrive): the read holds the
    topic's fields and one batch, never a list of batches to concatenate. The covariance
    diagonals are allocated at their first non-zero value (zeros before it)."""

    WIDTH: ClassVar[dict[str, int]] = {"header_ns": 0, "log_ns": 0, "position": 3, "orientation": 4, "velocity": 3,
             "pose_var": 6, "twist_var": 6}  # fmt: skip

    def __init__(self, count: int, twist: bool) -> None:
        cap = max(int(count), 16)
        self.n = 0
        self.cols: dict[str, np.ndarray] = {
            k: np.empty((cap, w) if w else cap, np.int64 if not w else float)
            for k, w in self.WIDTH.items()
            if k not in ("pose_var", "twist_var") and (twist or k != "velocity")
        }

    def add(self, d: layout.Decoded, logs: np.ndarray) -> None:
        m = len(logs)
        a, b = self.n, self.n + m
        cap = len(self.cols["log_ns"])
        if b > cap:
            for k, old in self.cols.items():
                grown = np.zeros((max(b, 2 * cap), *old.shape[1:]), old.dtype)
                grown[:a] = old[:a]
                self.cols[k] = grown
            cap = len(self.cols["log_ns"])
        c = self.cols
        c["header_ns"][a:b] = d.header_ns
        c["log_ns"][a:b] = logs
        c["position"][a:b] = d.pose[:, :3]
        c["orientation"][a:b] = d.pose[:, 3:7]
        if "velocity" in c and d.twist is not None:
            c["velocity"][a:b] = d.twist[:, :3]
        for k in ("pose_var", "twist_var"):
            v = getattr(d, k)
            if v is None or (k not in c and not np.any(v != 0)):
                continue
            if k not in c:  # the first covariance recorded: zeros before it
                c["pose_var"], c["twist_var"] = np.zeros((cap, 6)), np.zeros((cap, 6))
            c[k][a:b] = v
        self.n = b

    def trajectory(self, info: TopicInfo, frame: str, child: str) -> Trajectory:
        """The topic in log-time order (stable: batches come in chunk order)."""
        n = self.n
        cols, self.cols = self.cols, {}
        for k, v in cols.items():  # allocated for more: keep only what was read
            cols[k] = v if len(v) == n else v[:n].copy()
        if np.any(cols["log_ns"][1:] < cols["log_ns"][:-1]):
            order = np.argsort(cols["log_ns"], kind="stable")
            for k in cols:  # one array at a time: one copy alive at once
                cols[k] = cols[k][order]
        return Trajectory(
            name=info.topic,
            msgtype=info.msgtype,
            header_ns=cols["header_ns"],
            log_ns=cols["log_ns"],
            position=cols["position"],
            orientation=cols["orientation"],
            velocity=cols.get("velocity"),
            frame_id=frame,
            child_frame_id=child,
            decoder="numpy",
            pose_var=cols.get("pose_var"),
            twist_var=cols.get("twist_var"),
        )
