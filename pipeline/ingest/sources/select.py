"""Which topic is the VIO and which the truth: explicit, or chosen when unambiguous.

VIO candidates are ``nav_msgs/msg/Odometry`` topics; when a bag has none, the other pose
topics (PoseStamped, PoseWithCovarianceStamped, TransformStamped) whose names do not say
ground truth. Truth candidates are the pose types (PoseStamped, PoseWithCovarianceStamped,
TransformStamped, Odometry, and TFMessage when ``--truth-frame`` is given; ``/tf_static``
never); when there is none but one TF topic, that topic (its reader then lists the
transforms to pass with ``--truth-frame``). Without flags the choice is made when there is
exactly one VIO and one (other) truth candidate. When types alone leave several, names
decide only if exactly one candidate's name says it is ground truth (``truth``, ``ground``,
``gt``, ``vicon``, ``mocap``, ``optitrack``, ``qualisys``, ``leica``); otherwise the command
stops, says which types it considered and lists the candidates with their types and counts.
"""

from __future__ import annotations

import re
from pathlib import Path

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.ingest.sources.base import TopicInfo
from qsls.pipeline.ingest.sources.msgtypes import ODOMETRY, POSE_COV, POSE_STAMPED, TF, TRANSFORM

VIO_TYPES = (ODOMETRY,)
POSE_ONLY_TYPES = (POSE_STAMPED, POSE_COV, TRANSFORM)
POSE_TYPES = (POSE_STAMPED, POSE_COV, TRANSFORM, ODOMETRY)
TRUTH_TYPES = (*POSE_TYPES, TF)
_TRUTH_NAME = re.compile(
    r"truth|ground|(^|[^a-z])gt([^a-z]|$)|vicon|mocap|optitrack|qualisys|leica", re.I
)


def describe(topics: list[TopicInfo], limit: int = 12) -> str:
    shown = [f"{t.topic} ({t.msgtype}, {t.count} msgs)" for t in topics[:limit]]
    if len(topics) > limit:
        shown.append(f"and {len(topics) - limit} more")
    return ", ".join(shown) or "none"


def find_topic(
    topics: list[TopicInfo], name: str, role: str, allowed: tuple[str, ...]
) -> TopicInfo:
    """The topic named ``name`` (leading '/' optional) with a type in ``allowed``."""
    want = name.strip()
    hits = [t for t in topics if t.topic == want] or [
        t for t in topics if t.topic.lstrip("/") == want.lstrip("/")
    ]
    if not hits:
        where = ", ".join(sorted({t.source.name for t in topics})) or "the sources"
        raise InputError(f"no topic {name} in {where}; topics there: {describe(topics, 30)}")
    if len(hits) > 1:
        files = ", ".join(str(t.source) for t in hits)
        raise InputError(
            f"topic {name} is in several sources ({files}); pass the {role} bag alone with --{role} FILE"
        )
    t = hits[0]
    if t.msgtype not in allowed:
        raise InputError(
            f"topic {t.topic} is {t.msgtype}, not a {role} message type; "
            f"use a topic of type {', '.join(allowed)}"
        )
    return t


def choose(
    vio_topics: list[TopicInfo],
    truth_topics: list[TopicInfo],
    vio_name: str | None,
    truth_name: str | None,
    truth_frame: str | None,
) -> tuple[TopicInfo, TopicInfo]:
    """The (vio, truth) topics; a one-line error listing candidates when ambiguous."""
    vio = find_topic(vio_topics, vio_name, "vio", POSE_TYPES) if vio_name else None
    truth = find_topic(truth_topics, truth_name, "truth", TRUTH_TYPES) if truth_name else None
    if truth is not None and truth.msgtype == TF and not truth_frame:
        raise InputError(
            f"topic {truth.topic} is {TF}; pass --truth-frame PARENT/CHILD to pick a transform"
        )

    def key(t: TopicInfo) -> tuple[str, Path]:
        return (t.topic, t.source)

    if vio is None:
        vio = choose_vio(vio_topics, {key(truth)} if truth else set())
    if truth is None:
        allowed = TRUTH_TYPES if truth_frame else POSE_TYPES
        cands = [
            t
            for t in truth_topics
            if t.msgtype in allowed and key(t) != key(vio) and t.topic != "/tf_static"
        ]
        if len(cands) > 1:
            named = [t for t in cands if _TRUTH_NAME.search(t.topic)]
            cands = named if len(named) == 1 else cands
        tf = [t for t in truth_topics if t.msgtype == TF and t.topic != "/tf_static"]
        if not cands and len(tf) == 1:
            return vio, tf[0]  # TF only: its reader lists the transforms for --truth-frame
        if len(cands) != 1:
            raise InputError(
                f"cannot choose the truth topic automatically ({len(cands)} candidates: "
                f"{describe(cands)}); pass --truth-topic"
                + ("" if cands else f" (topics: {describe(truth_topics)})")
            )
        truth = cands[0]
    return vio, truth


def choose_vio(topics: list[TopicInfo], taken: set[tuple[str, Path]]) -> TopicInfo:
    """The VIO topic: the one Odometry topic (names decide between several), else the one pose
    topic whose name does not say ground truth; a line saying what was considered otherwise."""
    free = [t for t in topics if (t.topic, t.source) not in taken]
    cands = [t for t in free if t.msgtype in VIO_TYPES]
    if len(cands) > 1:
        named = [t for t in cands if not _TRUTH_NAME.search(t.topic)]
        cands = named if len(named) == 1 else cands
    if len(cands) == 1:
        return cands[0]
    if cands:
        why = f"{len(cands)} Odometry topics: {describe(cands)}"
    else:
        poses = [t for t in free if t.msgtype in POSE_ONLY_TYPES]
        unnamed = [t for t in poses if not _TRUTH_NAME.search(t.topic)]
        if len(unnamed) == 1:
            return unnamed[0]
        why = "no nav_msgs/msg/Odometry topic, and " + (
            f"{len(unnamed)} pose topics not named as ground truth: {describe(unnamed)}"
            if unnamed
            else f"every pose topic is named as ground truth ({describe(poses)})"
            if poses
            else f"no pose topic either (topics: {describe(topics)})"
        )
    raise InputError(f"cannot choose the VIO topic automatically ({why}); pass --vio-topic")
