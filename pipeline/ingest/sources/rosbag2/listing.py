"""A rosbag2 folder listed from its ``metadata.yaml``, without opening rosbags' reader.

rosbags' ``AnyReader`` builds a typestore (importing a ROS 2 distribution's types) and
opens every storage file on opening (a sqlite3 storage: a scan of the whole ``messages``
table to count messages). For the fixed-layout pose topics the fast paths need only the
storage kind, the files and the topics with their types and counts, which the bag's
``metadata.yaml`` holds (rosbags reads them from there too). Anything the fast paths do
not read (message or file compression, another storage, a metadata file rosbags would
refuse) gives ``None``: rosbags' reader, which also reports what is wrong.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path, PurePath

from qsls.pipeline.ingest.sources.base import METADATA

STORAGES = ("sqlite3", "mcap")


@dataclass(frozen=True)
class Rosbag2Listing:
    """An uncompressed rosbag2 of CDR messages: its storage (``sqlite3`` or ``mcap``), its
    storage files and ``{topic: (type, count)}``."""

    storage: str
    files: list[Path]
    topics: dict[str, tuple[str, int]]


def open_rosbag2(folder: Path) -> Rosbag2Listing | None:
    """The listing of the bag in ``folder`` when its ``metadata.yaml`` describes an
    uncompressed sqlite3 or MCAP rosbag2 of CDR messages whose files all exist; None for
    anything else."""
    import yaml

    try:
        loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's parser when built
        meta = yaml.load((Path(folder) / METADATA).read_text(), Loader=loader)
        info = meta["rosbag2_bagfile_information"]
        storage = info["storage_identifier"]
        if int(info["version"]) > 9 or storage not in STORAGES:
            return None
        if (info.get("compression_mode") or "none").lower() != "none":
            return None
        files = [Path(folder) / PurePath(p).name for p in info["relative_file_paths"]]
        topics: dict[str, tuple[str, int]] = {}
        for entry in info["topics_with_message_count"]:
            t = entry["topic_metadata"]
            if t["serialization_format"] != "cdr":
                return None
            prev = topics.get(t["name"], (t["type"], 0))
            if prev[0] != t["type"]:
                return None
            topics[t["name"]] = (t["type"], prev[1] + int(entry["message_count"]))
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError):
        return None
    if not files or not all(f.is_file() for f in files):
        return None
    return Rosbag2Listing(storage, files, topics)
