"""Ingest benchmark: the numpy fast path against rosbags' per-message deserializer.

Bags (written once under benchmarks/_work/, reused afterwards):
  (a) ROS1, 100k nav_msgs/Odometry (VIO, 200 Hz) + 100k geometry_msgs/PoseStamped
      (motion capture, 200 Hz) = 200k messages over 500 s;
  (b) the same with 640x480 mono8 camera images interleaved (>= 500 MB), uncompressed;
  (c) (b) with LZ4 chunk compression;
and (a), (b) as ROS2-sqlite3 and ROS2-MCAP (rosbag2 folders, uncompressed MCAP chunks) and as
a plain MCAP file with zstd chunks (images in the same chunks are decompressed too).

For each bag, in the same run:
  - ``qsls ingest`` end to end (read both topics, offset, alignment, resampling,
    flight.parquet) with the fast decoder and with ``decoder="deserializer"`` (every
    message through rosbags' per-message deserializer, what evo does);
  - reading the two topics only, both ways, and rosbags' raw message iteration (the floor
    of any reader that goes through ``messages()``);
  - MCAP only: reading the two topics through the per-message readers (``mcap``/rosbags
    iteration, then the numpy decoder): the MCAP path before the whole-chunk decoder;
  - ``qsls ingest`` as a user runs it, a fresh process each time (interpreter start, imports
    and console output included), fast and with ``decoder: deserializer`` from a config.

Run: python benchmarks/bench_ingest.py [--quick] [--smoke]

``--smoke`` (``smokemode.py``): 2 000 messages per bag (5 s: ingest needs 3 s of overlap)
and four images, built in a temporary folder, one run per cell, ``qsls ingest`` as a process
on the two ROS1 bags only.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from smokemode import add_flag, require, work_dir

ROOT = Path(__file__).resolve().parents[1]
WORK = work_dir(ROOT / "benchmarks" / "_work")
sys.path.insert(0, str(ROOT))

from qsls.pipeline.core.artifacts import _hash_file  # noqa: E402
from qsls.pipeline.ingest.sources.bags import BagSource  # noqa: E402
from qsls.pipeline.ingest.sources.messages import ImageStream  # noqa: E402
from qsls.pipeline.ingest.sources.write import write_bag  # noqa: E402
from qsls.pipeline.ingest.stage import IngestOptions, ingest  # noqa: E402
from tests.bagfixtures import make_flight  # noqa: E402

FORMATS = ("ros1", "ros2-sqlite", "ros2-mcap", "mcap-zstd")


def build(
    n_pose: int, image_mb: float, compression: str | None, name: str, fmt: str = "ros1"
) -> Path:
    path = WORK / name
    if path.exists():
        return path
    hz = 200.0
    f = make_flight(duration=n_pose / hz, vio_hz=hz, truth_hz=hz, dropouts=())
    truth = f.truth
    # the truth fixture runs 1 s longer at both ends: keep n_pose messages
    keep = slice(0, n_pose)
    truth = type(truth)(
        truth.topic, truth.header_ns[keep], truth.log_ns[keep], truth.position[keep],
        truth.orientation[keep], truth.msgtype,
    )  # fmt: skip
    streams: list = [f.vio, truth]
    if image_mb:
        n_img = int(np.ceil(image_mb * 1e6 / (640 * 480)))
        ts = np.linspace(f.vio.log_ns[0], f.vio.log_ns[-1], n_img).astype(np.int64)
        streams.append(ImageStream("/cam0/image_raw", ts, ts, 480, 640))
    t0 = time.perf_counter()
    write_bag(path, streams, fmt, compression=compression)
    print(f"  wrote {name}: {size_mb(path):.0f} MB in {time.perf_counter() - t0:.1f} s")
    return path


def size_mb(path: Path) -> float:
    return sum(f.stat().st_size for f in _files(path)) / 1e6


def _files(path: Path) -> list[Path]:
    return [path] if path.is_file() else sorted(f for f in path.rglob("*") if f.is_file())


REPEAT = 3
"""Runs per timed cell (best of); 1 in smoke mode."""


def timed_value(fn, repeat: int = 1) -> tuple[float, Any]:
    """The best of ``repeat`` wall times of ``fn()`` and its last value."""
    best, value = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        value = fn()
        best = min(best, time.perf_counter() - t0)
    return best, value


def timed(fn, repeat: int = 1) -> float:
    return timed_value(fn, repeat)[0]


def run_ingest(bag: Path, decoder: str, repeat: int | None = None) -> tuple[float, Any]:
    """Best wall seconds of ``qsls ingest`` in this process, and its result."""
    out = WORK / f"out_{bag.stem}_{decoder}"
    o = IngestOptions(vio_topic="/vio/odom", truth_topic="/mocap/pose", decoder=decoder)
    t = timed_value(lambda: ingest([bag], o, out, force=True), repeat=repeat or REPEAT)
    shutil.rmtree(out, ignore_errors=True)
    return t


def paired(a: Path, b: Path, n: int = 5) -> tuple[float, float, float]:
    """Fast ingest of ``a`` and ``b`` alternately, ``n`` times each (the same cache and load
    for both): (best a, best b, median of the per-pair ratios b_i / a_i)."""
    ta, tb = [], []
    for _ in range(n):
        ta.append(run_ingest(a, "fast", repeat=1)[0])
        tb.append(run_ingest(b, "fast", repeat=1)[0])
    return min(ta), min(tb), float(np.median(np.array(tb) / np.array(ta)))


def run_cli(bag: Path, decoder: str, repeat: int) -> float:
    """Wall time of ``qsls ingest`` in a fresh interpreter (best of ``repeat``)."""
    out = WORK / f"cli_{bag.stem}_{decoder}"
    cfg = WORK / "deserializer.yaml"
    cfg.write_text("ingest:\n  decoder: deserializer\n")
    cmd = [sys.executable, "-m", "qsls.cli.main", "ingest", str(bag), "--vio-topic", "/vio/odom",
           "--truth-topic", "/mocap/pose", "--out", str(out), "--force"]  # fmt: skip
    if decoder != "fast":
        cmd += ["--config", str(cfg)]

    def go() -> None:
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode:
            raise SystemExit(f"qsls ingest {bag.name} failed: {done.stderr.strip()[-300:]}")

    t = timed(go, repeat)
    shutil.rmtree(out, ignore_errors=True)
    return t


def read_per_message(bag: Path) -> int:
    """The MCAP read before the chunk decoder: raw messages one by one, decoded at once."""
    from qsls.pipeline.core.progress import NULL_PROGRESS

    with BagSource(bag) as s:
        infos = [t for t in s.topics() if t.topic in ("/vio/odom", "/mocap/pose")]
        raws = s._raw_pass(infos, NULL_PROGRESS)
        trajs = [s._decode(i, raws[i.topic], None, True) for i in infos]
    require(all(t.decoder == "numpy" for t in trajs), f"{bag.name}: the numpy decoder read it")
    return sum(len(t) for t in trajs)


def read_both(bag: Path, fast: bool) -> int:
    with BagSource(bag) as s:
        return len(s.read("/vio/odom", fast=fast)) + len(s.read("/mocap/pose", fast=fast))


def raw_iteration(bag: Path) -> int:
    from rosbags.highlevel import AnyReader

    n = 0
    with AnyReader([bag]) as r:
        conns = [c for c in r.connections if c.topic in ("/vio/odom", "/mocap/pose")]
        for _ in r.messages(connections=conns):
            n += 1
    return n


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="20k messages and 50 MB of images")
    add_flag(ap)
    args = ap.parse_args()
    global REPEAT
    n_pose, mb = (10_000, 50.0) if args.quick else (100_000, 520.0)
    tag = "quick" if args.quick else "full"
    pairs_n, reads_n, cli_n = 5, 2, 3
    if args.smoke:
        n_pose, mb, tag, REPEAT, pairs_n, reads_n, cli_n = 1_000, 1.0, "smoke", 1, 1, 1, 1
    WORK.mkdir(parents=True, exist_ok=True)
    bags = {}
    for fmt in FORMATS:
        ext = {"ros1": ".bag", "mcap-zstd": ".mcap"}.get(fmt, "")
        kind, _, comp = fmt.partition("-") if fmt == "mcap-zstd" else (fmt, "", "")
        for key, img in (("a", 0.0), ("b", mb)):
            label = f"{fmt} ({key}) {'+ images' if img else 'poses only'}"
            bags[label] = build(n_pose, img, comp or None, f"{key}_{tag}_{fmt}{ext}", kind)
    bags["ros1 (b) + images, LZ4"] = build(n_pose, mb, "lz4", f"b_lz4_{tag}.bag")
    n_msgs = 2 * n_pose
    run_ingest(bags["ros1 (a) poses only"], "fast")  # warm-up: imports (pyarrow) once
    # The images ratio with the two bags of a format ingested alternately, first: in the main
    # table each bag's runs are minutes apart and follow other bags' (the deserializer's among
    # them), so the two sides of the ratio are timed under different conditions.
    pairs = {
        fmt: paired(bags[f"{fmt} (a) poses only"], bags[f"{fmt} (b) + images"], pairs_n)
        for fmt in FORMATS
    }
    rows = []
    for label, bag in bags.items():
        size = size_mb(bag)
        ingest_fast, fast_res = run_ingest(bag, "fast")
        ingest_slow, slow_res = run_ingest(bag, "deserializer")
        require(
            (fast_res.samples, fast_res.time_offset_s)
            == (slow_res.samples, slow_res.time_offset_s),
            f"{label}: both decoders give the same samples and clock offset",
        )
        read_fast, n_fast = timed_value(lambda bag=bag: read_both(bag, True), repeat=reads_n)
        read_slow, n_slow = timed_value(lambda bag=bag: read_both(bag, False))
        require(n_fast == n_slow == n_msgs, f"{label}: both reads give {n_msgs} messages")
        raw = timed(lambda bag=bag: raw_iteration(bag)) if "mcap-zstd" not in label else np.nan
        before = timed(lambda bag=bag: read_per_message(bag)) if "mcap" in label else np.nan
        sha = timed(lambda bag=bag: sum(len(_hash_file(f)) for f in _files(bag)))
        rows.append((label, size, ingest_fast, ingest_slow, read_fast, read_slow, raw, before, sha))
    print(
        f"\n{n_msgs} Odometry+PoseStamped messages per bag; seconds (messages/s); ingest: best"
        f" of {REPEAT} each, reads: fast best of {reads_n}, the others one run\n"
    )
    head = (
        f"{'bag':34s} {'MB':>6s} | {'ingest fast':>18s} {'ingest deser.':>18s} {'speed-up':>8s}"
        f" | {'read fast':>9s} {'read deser.':>11s} {'raw iter':>8s} {'per-msg':>7s}"
        f" {'sha256':>6s}"
    )
    print(head)
    print("-" * len(head))
    for label, size, f_, s_, rf, rs, raw, before, sha in rows:
        print(
            f"{label:34s} {size:6.0f} | {f_:7.2f} ({n_msgs / f_:8.0f}) {s_:7.2f} ({n_msgs / s_:8.0f}) "
            f"{s_ / f_:7.1f}x | {rf:9.2f} {rs:11.2f} {raw:8.2f} {before:7.2f} {sha:6.2f}"
        )
    print(
        "(per-msg: MCAP read through the per-message readers, the path before the chunk decoder;"
        " raw iter: rosbags' messages(), which cannot open a plain MCAP)"
    )
    by = {r[0]: r for r in rows}
    print()
    for fmt in FORMATS:
        a, b = by[f"{fmt} (a) poses only"], by[f"{fmt} (b) + images"]
        print(
            f"{fmt:12s} speed-up over the deserializer path {a[3] / a[2]:5.1f}x (target >= 3x); "
            f"with images / without {b[2] / a[2]:4.2f}x (target <= 1.3x; the read alone "
            f"{b[4] / a[4]:4.2f}x, and ingest hashes every input byte for the manifest: "
            f"sha256 {b[8]:.2f} s, in parallel with the read)"
        )
    print(
        f"\nwith images / without, the two bags ingested alternately ({pairs_n} runs each, before"
        " the table above):\n"
    )
    head = f"{'format':12s} | {'without':>8s} {'with':>8s} | {'best/best':>9s} {'median pair':>11s}"
    print(head)
    print("-" * len(head))
    for fmt in FORMATS:
        ta, tb, med = pairs[fmt]
        target = "" if fmt == "mcap-zstd" else "  (target <= 1.3x)"
        print(f"{fmt:12s} | {ta:8.2f} {tb:8.2f} | {tb / ta:8.2f}x {med:10.2f}x{target}")
    print(
        "\nqsls ingest as a process, what a user types (interpreter start, imports and console"
        f" output included; best of {cli_n} each):\n"
    )
    head = (
        f"{'bag':34s} | {'fast':>6s} {'deser.':>7s} {'speed-up':>8s} | "
        f"{'with images / without':>21s}"
    )
    print(head)
    print("-" * len(head))
    cli: dict[str, float] = {}
    for label, bag in bags.items():
        if args.smoke and label not in ("ros1 (a) poses only", "ros1 (b) + images"):
            continue
        fast, slow = run_cli(bag, "fast", cli_n), run_cli(bag, "deserializer", cli_n)
        cli[label] = fast
        fmt = label.split(" ")[0]
        ratio = ""
        if "(b) + images" in label and f"{fmt} (a) poses only" in cli and "LZ4" not in label:
            ratio = f"{fast / cli[f'{fmt} (a) poses only']:20.2f}x"
        print(f"{label:34s} | {fast:6.2f} {slow:7.2f} {slow / fast:7.1f}x | {ratio}")


if __name__ == "__main__":
    main()
