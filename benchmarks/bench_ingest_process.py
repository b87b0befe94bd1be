"""``qsls ingest`` as a process against reading the same two topics message by message.

Issue 27's target: ``qsls ingest`` of a 200 000-message bag (100 000 nav_msgs/Odometry and
100 000 geometry_msgs/PoseStamped at 200 Hz), as a fresh process, at least 3x faster than
reading the same two topics message by message with rosbags' deserializer in a fresh
process. Both sides are what a user types, interpreter start and imports included:

- ``qsls ingest BAG`` (read both topics, time offset, alignment, resampling, hashing,
  flight.parquet and manifest, console output);
- the reader: ``rosbags.highlevel.AnyReader`` over the two topics' connections,
  ``reader.deserialize(raw, msgtype)`` per message and its stamp, position and orientation
  kept in lists, then numpy arrays (what evo and most scripts do). A plain MCAP file, which
  AnyReader cannot open, is read with the ``mcap`` package's reader and rosbags'
  ``typestore.deserialize_cdr``;
- for reference, the previous baseline of ``bench_ingest.py``: ``qsls ingest`` itself with
  ``decoder: deserializer`` (the same per-message reading plus everything ingest does
  after it), which makes a larger ratio.

The bags are those of ``bench_ingest.py`` (poses only, built once under benchmarks/_work/).
Each cell is the median of ``--repeat`` fresh processes (5), taken in turns; wall and CPU
seconds (user + system, all threads) are both printed, CPU moving less on a shared machine.

Memory (issue 37's target: peak RSS independent of the bag's length, a 2 000 000-message bag
in at most 300 MB, still at least 3x faster than the reader): the same two processes on a
long bag of each format (``--long`` messages, 2 000 000 by default: 1 000 000 Odometry and
1 000 000 PoseStamped at 200 Hz, 5000 s; built once, 0.2 to 1.1 GB) and on the short one,
one fresh run each, with the peak resident set of each process (``os.wait4``'s
``ru_maxrss``: file pages mapped and touched count too).

Run: python benchmarks/bench_ingest_process.py [--quick] [--repeat N] [--long N | --long 0]
[--memory-only] [--smoke]

``--smoke`` (``smokemode.py``): bags of 2 000 messages (and a long one of 4 000, ROS1 only) in
a temporary folder, one run per cell, no untimed runs first.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_ingest import WORK, build
from fresh import median_runs, peak_run
from smokemode import add_flag, requested

READER = r"""
import sys
from pathlib import Path

import numpy as np
from rosbags.typesys import Stores, get_typestore

bag, plain_mcap = Path(sys.argv[1]), sys.argv[2] == "mcap"
topics = ("/vio/odom", "/mocap/pose")
rows = {t: [] for t in topics}


def row(msg):
    pose = msg.pose.pose if hasattr(msg, "twist") else msg.pose
    st, p, q = msg.header.stamp, pose.position, pose.orientation
    ns = getattr(st, "nanosec", None)
    ns = st.nsec if ns is None else ns
    return (st.sec * 1_000_000_000 + ns, p.x, p.y, p.z, q.x, q.y, q.z, q.w)


ts = get_typestore(Stores.ROS2_HUMBLE)
if plain_mcap:
    from mcap.reader import make_reader

    with open(bag, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(topics=topics):
            rows[channel.topic].append(row(ts.deserialize_cdr(message.data, schema.name)))
else:
    from rosbags.highlevel import AnyReader

    with AnyReader([bag], default_typestore=ts) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        for conn, _, raw in reader.messages(connections=conns):
            rows[conn.topic].append(row(reader.deserialize(raw, conn.msgtype)))
arrays = {t: np.array(v, dtype=float) for t, v in rows.items()}
print(sum(len(a) for a in arrays.values()))
"""

FORMATS = {  # label: (bench_ingest format, file suffix, plain MCAP)
    "ros1": ("ros1", ".bag", False),
    "ros2-sqlite3": ("ros2-sqlite", "", False),
    "ros2-mcap": ("ros2-mcap", "", False),
    "mcap (zstd)": ("mcap-zstd", ".mcap", True),
}


def commands(bag: Path, plain_mcap: bool) -> dict[str, list[str]]:
    """The three fresh processes timed on ``bag``."""
    cfg = WORK / "deserializer.yaml"
    cfg.write_text("ingest:\n  decoder: deserializer\n")
    qsls = [sys.executable, "-m", "qsls.cli.main", "ingest", str(bag), "--vio-topic",
            "/vio/odom", "--truth-topic", "/mocap/pose", "--force", "--out"]  # fmt: skip
    return {
        "qsls": [*qsls, str(WORK / f"cli_{bag.stem}")],
        "reader": [sys.executable, "-c", READER, str(bag), "mcap" if plain_mcap else "bag"],
        "deser": [*qsls, str(WORK / f"cli_{bag.stem}_deser"), "--config", str(cfg)],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="20k messages instead of 200k")
    ap.add_argument("--repeat", type=int, default=5, help="fresh processes per cell (median)")
    ap.add_argument(
        "--long",
        type=int,
        default=2_000_000,
        help="messages of the memory run's long bags (0: none)",
    )
    ap.add_argument("--memory-only", action="store_true", help="the memory runs alone")
    add_flag(ap)
    args = ap.parse_args()
    n_pose = 10_000 if args.quick else 100_000
    tag = "quick" if args.quick else "full"
    memory_formats = list(FORMATS)
    if args.smoke:
        n_pose, tag, args.repeat, args.long, memory_formats = 1_000, "smoke", 1, 4_000, ["ros1"]
    WORK.mkdir(parents=True, exist_ok=True)
    if args.memory_only:
        memory(n_pose, args.long // 2, tag, memory_formats)
        return
    rows = []
    for label, (fmt, ext, plain) in FORMATS.items():
        kind, _, comp = fmt.partition("-") if plain else (fmt, "", "")
        bag = build(n_pose, 0.0, comp or None, f"a_{tag}_{fmt}{ext}", kind)
        t = median_runs(commands(bag, plain), args.repeat)
        if int(t["reader"][2].strip()) != 2 * n_pose:
            raise SystemExit(f"the reader read {t['reader'][2].strip()} messages of {bag.name}")
        rows.append((label, t["qsls"][:2], t["reader"][:2], t["deser"][:2]))
        for d in WORK.glob(f"cli_{bag.stem}*"):
            shutil.rmtree(d, ignore_errors=True)
    print(
        f"\n{2 * n_pose} messages ({n_pose} Odometry + {n_pose} PoseStamped, 200 Hz), poses"
        f" only; a fresh process each, median of {args.repeat} taken in turns; wall seconds"
        " (CPU seconds: user + system of the process, all its threads)\n"
    )
    head = (
        f"{'bag':14s} | {'qsls ingest':>13s} | {'reader':>13s} {'wall':>6s} {'CPU':>6s} | "
        f"{'ingest, deser.':>14s} {'wall':>6s} {'CPU':>6s}"
    )
    print(head)
    print("-" * len(head))
    for label, (q, qc), (r, rc), (o, oc) in rows:
        print(
            f"{label:14s} | {q:5.2f} ({qc:4.2f}) | {r:5.2f} ({rc:4.2f}) {r / q:5.1f}x {rc / qc:5.1f}x"
            f" | {o:6.2f} ({oc:4.2f}) {o / q:5.1f}x {oc / qc:5.1f}x"
        )
    print()
    for label, (q, qc), (r, rc), _ in rows:
        met = "met" if min(r / q, rc / qc) >= 3 else "NOT met"
        print(
            f"{label}: qsls ingest {r / q:.1f}x faster than the reader in wall time,"
            f" {rc / qc:.1f}x in CPU time (target >= 3x: {met})"
        )
    if args.long:
        memory(n_pose, args.long // 2, tag, memory_formats)
    print(
        "\nreader: the two topics read message by message with rosbags' deserializer (issue"
        " 27's target: qsls ingest >= 3x faster); ingest, deser.: qsls ingest with"
        " decoder: deserializer, bench_ingest.py's baseline. qsls ingest's CPU includes the"
        " sha256 of the whole bag for the manifest, computed in a second thread. Wall times"
        " on a machine shared with other jobs move more than CPU times."
    )


MEMORY_TARGET_MB = 300.0


def memory(n_short: int, n_long: int, tag: str, formats: list[str] | None = None) -> None:
    """Peak RSS, wall and CPU seconds of ``qsls ingest`` and of the reader, one fresh run
    each, on the short and the long bag of every format in ``formats`` (all by default;
    module docstring)."""
    rows = []
    for label in formats or FORMATS:
        fmt, ext, plain = FORMATS[label]
        kind, _, comp = fmt.partition("-") if plain else (fmt, "", "")
        for n in (n_short, n_long):
            name = f"a_{tag}_{fmt}{ext}" if n == n_short else f"long{2 * n}_{fmt}{ext}"
            bag = build(n, 0.0, comp or None, name, kind)
            cmds = commands(bag, plain)
            if not requested():
                peak_run(cmds["qsls"])  # untimed: the bag into the page cache, for both sides
            q = peak_run(cmds["qsls"])
            r = peak_run(cmds["reader"])
            if int(r[3].strip()) != 2 * n:
                raise SystemExit(f"the reader read {r[3].strip()} messages of {bag.name}")
            rows.append((label, 2 * n, q[:3], r[:3]))
            for d in WORK.glob(f"cli_{bag.stem}*"):
                shutil.rmtree(d, ignore_errors=True)
    print("\nmemory: one fresh process each; wall seconds (CPU seconds), peak resident set (MB)\n")
    head = (
        f"{'bag':14s} {'messages':>9s} | {'qsls ingest':>13s} {'RSS':>6s} | {'reader':>14s}"
        f" {'RSS':>6s} | {'faster, wall':>12s} {'CPU':>5s}"
    )
    print(head)
    print("-" * len(head))
    for label, n, (q, qc, qm), (r, rc, rm) in rows:
        print(
            f"{label:14s} {n:9d} | {q:6.2f} ({qc:5.2f}) {qm:6.0f} | {r:6.2f} ({rc:6.2f}) {rm:6.0f}"
            f" | {r / q:11.1f}x {rc / qc:4.1f}x"
        )
    print()
    for label, n, (q, qc, qm), (r, rc, _) in rows:
        if n != 2 * n_long:
            continue
        met = "met" if qm <= MEMORY_TARGET_MB and min(r / q, rc / qc) >= 3 else "NOT met"
        print(
            f"{label}: {n} messages in {qm:.0f} MB peak RSS (target <= {MEMORY_TARGET_MB:.0f} MB),"
            f" {r / q:.1f}x faster than the reader in wall time, {rc / qc:.1f}x in CPU time"
            f" (target >= 3x): {met}"
        )


if __name__ == "__main__":
    main()
