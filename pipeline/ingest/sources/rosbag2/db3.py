"""A lone rosbag2 ``.db3`` file, opened as a bag: a temporary folder holding a link to it and
the ``metadata.yaml`` rosbags needs, made from the file's own tables."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.ingest.sources.anyreader import temp_link
from qsls.pipeline.ingest.sources.base import BAG_HINT, METADATA, locked_hint


def db3_folder(db: Path) -> Path:
    """A rosbag2 folder for ``db`` (the caller removes it): a link to it and metadata from its
    ``topics`` and ``messages`` tables."""
    import yaml

    try:
        con = sqlite3.connect(f"file:{db.resolve()}?mode=ro", uri=True)
        try:
            topics = con.execute(
                "SELECT id, name, type, serialization_format FROM topics"
            ).fetchall()
            stats = {
                r[0]: r[1:]
                for r in con.execute(
                    "SELECT topic_id, COUNT(*), MIN(timestamp), MAX(timestamp) "
                    "FROM messages GROUP BY topic_id"
                )
            }
        finally:
            con.close()
    except sqlite3.Error as exc:
        if hint := locked_hint(exc):
            raise InputError(f"{db}: {hint}") from None
        raise InputError(f"{db}: not a readable rosbag2 sqlite3 file ({exc}); {BAG_HINT}") from None
    folder = temp_link(db, db.name).parent
    starts = [s[1] for s in stats.values()] or [0]
    stops = [s[2] for s in stats.values()] or [0]
    meta = {
        "rosbag2_bagfile_information": {
            "version": 5,
            "storage_identifier": "sqlite3",
            "relative_file_paths": [db.name],
            "duration": {"nanoseconds": int(max(stops) - min(starts))},
            "starting_time": {"nanoseconds_since_epoch": int(min(starts))},
            "message_count": int(sum(s[0] for s in stats.values())),
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": name,
                        "type": typ,
                        "serialization_format": fmt,
                        "offered_qos_profiles": "",
                    },
                    "message_count": int(stats.get(tid, (0,))[0]),
                }
                for tid, name, typ, fmt in topics
            ],
            "compression_format": "",
            "compression_mode": "",
        }
    }
    (folder / METADATA).write_text(yaml.safe_dump(meta))
    return folder
