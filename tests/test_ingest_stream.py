"""Ingest in bounded memory (issue 37): the bag is read in batches and the stream-long steps
run on blocks of rows, and ``flight.parquet`` holds the same values as before.

- The values of ``flight.parquet`` for a bag written here equal a digest taken with the code
  before the change (commit 9c4cbe1: the whole bag in memory at once), in three formats.
- With batches, SQL ranges and row blocks shrunk to a few kilobytes and a thousand rows (so
  every streamed loop runs many times), the file is byte-identical to the default run's.

The 2 000 000-message peak-RSS measurement is a benchmark, not a test
(``benchmarks/bench_ingest_memory.py``).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from qsls.pipeline.ingest.sources.write import write_bag
from qsls.pipeline.ingest.stage import IngestOptions, ingest
from tests.bagfixtures import make_flight

FORMATS = {"ros1": ("f.bag", None), "ros2-sqlite": ("f_sqlite", None), "mcap": ("f.mcap", "zstd")}

BEFORE = "465c505d74611c97693fbf20a9a5b3e7cb2ac0795a2dd5f2684fd3248583be9c"
"""sha256 of the column names and values of ``flight.parquet`` for :func:`bags`' flight,
ingested by the code before the streaming reader (the same in the three formats)."""


def digest(parquet: Path) -> str:
    t = pq.read_table(parquet)
    h = hashlib.sha256()
    for name, col in zip(t.column_names, t.columns, strict=True):
        h.update(name.encode())
        h.update(col.to_numpy().tobytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("stream")
    f = make_flight(duration=40.0, vio_hz=200.0, truth_hz=240.0, seed=3)
    return {
        fmt: write_bag(d / name, [f.vio, f.truth], fmt, compression=comp)
        for fmt, (name, comp) in FORMATS.items()
    }


def _small_blocks(monkeypatch: pytest.MonkeyPatch) -> None:
    from qsls.pipeline.ingest import align, streams, timesync
    from qsls.pipeline.ingest.sources.mcap import chunks as mcapchunks
    from qsls.pipeline.ingest.sources.ros1 import index as ros1index
    from qsls.pipeline.ingest.sources.rosbag2 import sqlite

    for mod, name, value in (
        (ros1index, "_BATCH_BYTES", 30_000),
        (mcapchunks, "_BATCH_BYTES", 30_000),
        (sqlite, "_QUERY_BYTES", 20_000),
        (streams, "CHUNK", 1000),
        (align, "_ROWS", 1000),
        (timesync, "_ROWS", 1000),
    ):
        monkeypatch.setattr(mod, name, value)


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_flight_values_equal_the_whole_bag_reader(
    bags: dict[str, Path], fmt: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ingest([bags[fmt]], IngestOptions(), tmp_path / "a")
    assert digest(tmp_path / "a" / "flight.parquet") == BEFORE
    _small_blocks(monkeypatch)
    ingest([bags[fmt]], IngestOptions(), tmp_path / "b")
    a, b = (tmp_path / k / "flight.parquet" for k in "ab")
    assert a.read_bytes() == b.read_bytes()
