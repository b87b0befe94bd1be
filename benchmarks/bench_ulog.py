"""PX4 ULog reading: ``read_odometry`` and ``qsls ingest`` against pyulog into numpy by hand.

A long log is written once with the project's ULog writer (under benchmarks/_work/): a
flight of ``--minutes`` minutes (10 by default) with ``vehicle_visual_odometry`` and
``vehicle_mocap_odometry`` at 200 Hz, ``vehicle_attitude`` at 250 Hz,
``vehicle_local_position`` at 100 Hz and ``sensor_combined`` at 500 Hz (the topics ingest
skips are most of the file, as on a vehicle). Each way is a fresh process (interpreter and
imports outside the timing, which covers the reading only), ``--repeat`` times in turns
(3), best wall time and least CPU time kept; its peak resident set is the process's
``VmHWM`` (imports included: the "imports only" row is that floor):

- ``read_odometry``: :func:`qsls.pipeline.ingest.sources.ulog.reader.read_odometry` of the
  VIO topic (the framing walked, pyulog on the VIO's messages alone, ENU/FLU conversion,
  a ``Trajectory``);
- the naive way: ``pyulog.ULog(path, [topic])`` then ``np.column_stack`` of the timestamp,
  position, quaternion and velocity fields (no frame conversion);
- ``qsls ingest`` of the log (both topics in one pass, offset, alignment, resampling,
  flight.parquet), and beside it the naive reading of the same two topics.

Before timing, both ways read the same topic in this process and must give the same
samples (positions equal to the bit after the NED -> ENU permutation).

Run: python benchmarks/bench_ulog.py [--minutes M] [--repeat N] [--smoke]

``--smoke`` (``smokemode.py``): a 12 s log in a temporary folder, one run per way.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from smokemode import add_flag, requested, require, work_dir

ROOT = Path(__file__).resolve().parents[1]
WORK = work_dir(ROOT / "benchmarks" / "_work")
sys.path.insert(0, str(ROOT))

VIO, MOCAP = "vehicle_visual_odometry", "vehicle_mocap_odometry"


def build(minutes: float) -> tuple[Path, int]:
    """The log (written once per length) and its message count."""
    from qsls.pipeline.ingest.sources.ulog.writer import LogContent, Topic, write_ulog
    from tests.test_ulog import attitude, local_position, odometry, q_ned_of_yaw_pitch

    path = WORK / f"ulog_{minutes:g}min.ulg"
    dur = minutes * 60.0
    rng = np.random.default_rng(0)

    def circle(hz: float, start_us: int) -> tuple[np.ndarray, ...]:
        t = np.arange(0.0, dur, 1.0 / hz)
        w = 2 * np.pi / 10.0  # radius 2 m, 10 s a lap, 1.5 m up (NED z -1.5)
        p = np.column_stack([2 * np.cos(w * t), 2 * np.sin(w * t), np.full(len(t), -1.5)])
        v = np.column_stack([-2 * w * np.sin(w * t), 2 * w * np.cos(w * t), np.zeros(len(t))])
        yaw = (w * t + np.pi / 2 + np.pi) % (2 * np.pi) - np.pi
        return start_us + np.round(t * 1e6).astype(np.int64), p, v, yaw

    t, p, v, yaw = circle(200.0, 1_000_000)
    q = q_ned_of_yaw_pitch(yaw)
    vio = odometry(VIO, t + 2000, p + rng.normal(scale=0.003, size=p.shape), q, v, sample_us=t)
    mocap = odometry(MOCAP, t + 500, p, q, np.full_like(p, np.nan), sample_us=t)
    ta, _, _, ya = circle(250.0, 1_000_300)
    att = attitude("vehicle_attitude", ta, q_ned_of_yaw_pitch(ya))
    tl, pl, vl, yl = circle(100.0, 1_000_700)
    lp = local_position("vehicle_local_position", tl, pl, vl, yl)
    ts = 1_000_100 + np.arange(int(dur * 500)) * 2000
    imu = Topic(
        "sensor_combined",
        [("uint64_t", "timestamp"), ("float[3]", "gyro_rad"), ("uint32_t", "gyro_integral_dt"),
         ("int32_t", "accelerometer_timestamp_relative"), ("float[3]", "accelerometer_m_s2"),
         ("uint32_t", "accelerometer_integral_dt"), ("uint8_t", "accelerometer_clipping")],
        {"timestamp": ts, "gyro_rad": rng.normal(size=(len(ts), 3)),
         "accelerometer_m_s2": rng.normal(size=(len(ts), 3))},
    )  # fmt: skip
    topics = [vio, mocap, att, lp, imu]
    count = sum(len(x.data["timestamp"]) for x in topics)
    if not path.exists():
        write_ulog(path, LogContent(topics, parameters={"SDLOG_PROFILE": 129}))
    return path, count


# --------------------------------------------------------------------------- the children
def peak_rss_mb() -> float:
    """This process's peak resident set (MB): ``VmHWM`` (the high-water mark of its own
    memory since its exec; ``ru_maxrss`` would keep the parent's from before the fork)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _naive(log: Path, topics: list[str]) -> int:
    from pyulog import ULog

    u = ULog(str(log), topics)
    rows = 0
    for d in u.data_list:
        x = d.data
        cols = ["timestamp", "timestamp_sample"]
        cols += [
            f"{f}[{i}]" for f, k in (("position", 3), ("q", 4), ("velocity", 3)) for i in range(k)
        ]
        rows += len(np.column_stack([x[c] for c in cols]))
    return rows


def child(way: str, log: Path, out: Path) -> None:
    """One way, timed here; prints ``{"wall", "cpu", "rss_mb", "rows"}``."""
    import pyulog  # noqa: F401  (imports outside the timing)

    from qsls.pipeline.ingest.sources.ulog.reader import read_odometry
    from qsls.pipeline.ingest.stage import IngestOptions, ingest

    t0, c0 = time.perf_counter(), time.process_time()
    rows = 0
    if way == "read":
        rows = len(read_odometry(log, VIO))
    elif way == "naive":
        rows = _naive(log, [VIO])
    elif way == "ingest":
        rows = ingest([log], IngestOptions(), out, force=True).samples
    elif way == "naive2":
        rows = _naive(log, [VIO, MOCAP])
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(json.dumps({"wall": wall, "cpu": cpu, "rss_mb": peak_rss_mb(), "rows": rows}))


def run_child(way: str, log: Path) -> dict:
    cmd = [sys.executable, __file__, "--child", way, str(log), str(WORK / "ulog_flight")]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"{way}: {done.stderr.strip()[-600:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


# --------------------------------------------------------------------------- main
def same_samples(log: Path) -> bool:
    """Both ways read the same VIO samples (positions to the bit, after NED -> ENU)."""
    from pyulog import ULog

    from qsls.pipeline.ingest.sources.ulog.reader import read_odometry

    tr = read_odometry(log, VIO)
    x = ULog(str(log), [VIO]).data_list[0].data
    ned = np.column_stack([x[f"position[{i}]"] for i in range(3)]).astype(float)
    return bool(
        np.array_equal(tr.position, np.column_stack([ned[:, 1], ned[:, 0], -ned[:, 2]]))
        and np.array_equal(tr.log_ns, x["timestamp"].astype(np.int64) * 1000)
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="log length (10)")
    ap.add_argument("--repeat", type=int, default=3, help="fresh runs per way (3)")
    ap.add_argument("--child", nargs=3, metavar=("WAY", "LOG", "OUT"), help=argparse.SUPPRESS)
    add_flag(ap)
    a = ap.parse_args()
    if a.child:
        child(a.child[0], Path(a.child[1]), Path(a.child[2]))
        return
    smoke = requested()
    minutes, repeat = (0.2, 1) if smoke else (a.minutes, a.repeat)
    WORK.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    log, count = build(minutes)
    built = time.perf_counter() - t0
    mb = log.stat().st_size / 1e6
    require(same_samples(log), "read_odometry and pyulog by hand give the same samples")
    ways = {
        "read": f"read_odometry({VIO})",
        "naive": "pyulog ULog(path, [topic]) + np.column_stack",
        "ingest": "qsls ingest (VIO + mocap, flight.parquet)",
        "naive2": "pyulog ULog(path, 2 topics) + column_stack",
        "imports": "imports only (the floor of the peak RSS)",
    }
    best: dict[str, dict] = {}
    for _ in range(repeat):
        for way in ways:
            r = run_child(way, log)
            b = best.setdefault(way, r)
            b.update(wall=min(b["wall"], r["wall"]), cpu=min(b["cpu"], r["cpu"]))
            b["rss_mb"] = max(b["rss_mb"], r["rss_mb"])
    require(best["read"]["rows"] == best["naive"]["rows"], "both ways read every VIO message")
    print(
        f"PX4 ULog: {minutes:g} min, {count:,} messages in 5 topics, {mb:.1f} MB "
        f"(written in {built:.1f} s; VIO and mocap odometry at 200 Hz, {best['read']['rows']:,} "
        "VIO messages)"
    )
    print(f"{'way':<46} {'wall s':>8} {'cpu s':>8} {'peak RSS MB':>12}")
    for way, label in ways.items():
        r = best[way]
        print(f"{label:<46} {r['wall']:>8.3f} {r['cpu']:>8.3f} {r['rss_mb']:>12.1f}")
    speed = best["naive"]["wall"] / best["read"]["wall"]
    extra = best["read"]["rss_mb"] - best["imports"]["rss_mb"]
    naive_extra = best["naive"]["rss_mb"] - best["imports"]["rss_mb"]
    print(
        f"read_odometry: {speed:.2f}x the naive way's speed; peak RSS above the imports "
        f"{extra:.1f} MB (naive {naive_extra:.1f} MB) for a {mb:.1f} MB log"
    )


if __name__ == "__main__":
    main()
