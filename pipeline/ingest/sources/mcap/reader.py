"""A plain MCAP file: the ``mcap`` package's reader and summary; fixed-layout topics through
the summary's chunk indexes (:mod:`.chunks`), the rest per message with ``mcap_ros2``'s
decoder. docs/ingest.md#formats.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import Progress
from qsls.pipeline.ingest.sources.anyreader import PROGRESS_STEP
from qsls.pipeline.ingest.sources.base import (
    IndexPlan,
    RawTopic,
    TopicInfo,
    damaged_hint,
)
from qsls.pipeline.ingest.sources.mcap.chunks import topic_batches
from qsls.pipeline.ingest.sources.msgtypes import normalize_type


class McapFileReader:
    """An open plain MCAP file (:class:`~qsls.pipeline.ingest.sources.base.BagReader`)."""

    cdr = True
    listed_by = "the bag"

    def __init__(self, path: Path) -> None:
        from mcap.reader import make_reader

        self.path = Path(path)
        self._fh: Any = open(self.path, "rb")  # noqa: SIM115 (closed in close())
        try:
            self._mcap = make_reader(self._fh, validate_crcs=True)
            summary = self._mcap.get_summary()
        except BaseException:
            self.close()
            raise
        if summary is None:
            self.close()
            raise InputError(
                f"{self.path}: MCAP file without a summary section; {damaged_hint('mcap')}"
            )
        self._summary = summary

    def topics(self) -> list[TopicInfo]:
        s = self._summary
        counts = s.statistics.channel_message_counts if s.statistics else {}
        out: dict[str, TopicInfo] = {}
        for cid, ch in s.channels.items():
            schema = s.schemas.get(ch.schema_id)
            mt = normalize_type(schema.name) if schema else "?"
            prev = out.get(ch.topic)
            n = int(counts.get(cid, 0)) + (prev.count if prev else 0)
            out[ch.topic] = TopicInfo(ch.topic, mt, n, self.path)
        return list(out.values())

    def indexed(self, infos: list[TopicInfo]) -> IndexPlan:
        ids = {info.topic: {k} for k, info in enumerate(infos)}
        return ids, lambda: topic_batches([self.path], infos, self._summary)

    def raw(self, infos: list[TopicInfo], progress: Progress) -> dict[str, RawTopic]:
        out: dict[str, RawTopic] = {i.topic: ([], [], None) for i in infos}
        n = 0
        for schema, channel, message in self._mcap.iter_messages(topics=list(out)):
            if channel.message_encoding != "cdr":
                raise InputError(
                    f"{self.path}: topic {channel.topic} is encoded as "
                    f"{channel.message_encoding!r}; qsls reads ROS2 messages (cdr encoding)"
                )
            raws, logs, known = out[channel.topic]
            if known is None:
                out[channel.topic] = (raws, logs, schema)
            raws.append(bytes(message.data))
            logs.append(int(message.log_time))
            n += 1
            if n % PROGRESS_STEP == 0:
                progress.advance(PROGRESS_STEP)
        progress.advance(n % PROGRESS_STEP)
        return out

    def deserialize(self, info: TopicInfo, raws: list[bytes], schema: Any) -> list[Any]:
        if not raws:
            return []
        from mcap_ros2.decoder import DecoderFactory

        dec = DecoderFactory().decoder_for("cdr", schema)
        if dec is None:
            raise InputError(f"{self.path}: cannot decode topic {info.topic} ({info.msgtype})")
        return [dec(x) for x in raws]

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None
