"""rosbags' ``AnyReader``, the per-message path shared by ROS1 and rosbag2 bags: opened on
first use (it builds a typestore and, on a sqlite3 storage, counts every message), its raw
messages in one pass, and a temporary link for a file rosbags will not open by its own name.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

from qsls.pipeline.core.progress import Progress
from qsls.pipeline.ingest.sources.base import RawTopic, TopicInfo
from qsls.pipeline.ingest.sources.msgtypes import typestore

PROGRESS_STEP = 4096
"""Messages between two progress updates of a per-message pass."""


def temp_link(src: Path, name: str) -> Path:
    """A link named ``name`` to ``src`` in a new temporary folder (the caller removes it)."""
    dst = Path(tempfile.mkdtemp(prefix="qsls-bag-")) / name
    os.symlink(Path(src).resolve(), dst)
    return dst


def open_anyreader(target: Path) -> Any:
    """rosbags' ``AnyReader`` on ``target``, opened (ROS2 Humble types by default)."""
    from rosbags.highlevel import AnyReader

    reader = AnyReader([target], default_typestore=typestore(ros1=False))
    reader.open()
    return reader


def anyreader_raw(reader: Any, infos: list[TopicInfo], progress: Progress) -> dict[str, RawTopic]:
    """``{topic: (raw messages, log stamps, None)}`` of ``infos`` in one pass of ``reader``."""
    out: dict[str, RawTopic] = {i.topic: ([], [], None) for i in infos}
    n = 0
    conns = [c for c in reader.connections if c.topic in out]
    for c, log, raw in reader.messages(connections=conns):
        raws, logs, _ = out[c.topic]
        raws.append(raw)
        logs.append(log)
        n += 1
        if n % PROGRESS_STEP == 0:
            progress.advance(PROGRESS_STEP)
    progress.advance(n % PROGRESS_STEP)
    return out
