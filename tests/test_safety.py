"""Nothing lost, nothing trusted blindly (issue 16): outputs never overwrite inputs, output
folders are locked, degenerate input is refused, through the public commands."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from qsls.pipeline.core.artifacts import sha256_path
from tests.test_fit import circle_states, vio_flights, write_flight

REPO = Path(__file__).resolve().parents[1]


def qsls(*args: object, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
    )


def one_line_error(proc: subprocess.CompletedProcess, code: int = 2) -> str:
    assert proc.returncode == code, (proc.returncode, proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, proc.stderr
    return lines[0]


# --------------------------------------------------------------------------- item 1
def test_force_never_destroys_an_input_folder(tmp_path):
    flights, _ = vio_flights(tmp_path / "flights", n=2)
    before = [sha256_path(f) for f in flights]
    parent = tmp_path / "flights"
    # the output contains the inputs
    msg = one_line_error(qsls("fit", *flights, "--out", parent, "--force", "--no-figures"))
    assert "contains the input" in msg
    # the output is an input
    msg = one_line_error(qsls("fit", *flights, "--out", flights[0], "--force", "--no-figures"))
    assert "is the input" in msg
    # the output lies inside an input, reached through a symlink
    link = tmp_path / "link"
    link.symlink_to(flights[1], target_is_directory=True)
    msg = one_line_error(qsls("fit", *flights, "--out", link / "fit", "--force"))
    assert "lies inside the input" in msg
    assert [sha256_path(f) for f in flights] == before
    assert sorted(p.name for p in parent.iterdir()) == ["flight0", "flight1"]

    fitted = tmp_path / "fit"
    ok = qsls("fit", *flights, "--out", fitted, "--no-figures", "--radius", "1.0")
    assert ok.returncode == 0, ok.stderr
    model_hash = sha256_path(fitted)
    msg = one_line_error(qsls("synth", "--model", fitted, "--out", fitted, "--force", "-T", "5"))
    assert "is the input" in msg
    assert sha256_path(fitted) == model_hash and (fitted / "error_model.yaml").is_file()


# --------------------------------------------------------------------------- item 2
def _tum(path: Path, t: np.ndarray, p: np.ndarray) -> Path:
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    path.write_text(
        "# t x y z qx qy qz qw\n"
        + "".join(
            f"{a:.6f} " + " ".join(f"{v:.6f}" for v in (*b, *c)) + "\n"
            for a, b, c in zip(t, p, q, strict=True)
        )
    )
    return path


def _circle(t: np.ndarray) -> np.ndarray:
    return np.c_[np.cos(t), np.sin(t), 1 + 0.1 * np.sin(3 * t)]


def test_one_stream_as_vio_and_truth_is_refused_at_ingest(tmp_path):
    t = np.arange(0, 20, 0.02)
    truth = _tum(tmp_path / "truth.tum", t, _circle(t))
    msg = one_line_error(qsls("ingest", "--vio", truth, "--truth", truth, "--out", tmp_path / "a"))
    assert "the VIO and truth streams are the same" in msg
    copy = _tum(tmp_path / "copy.tum", t, _circle(t))  # another file, identical samples
    msg = one_line_error(qsls("ingest", "--vio", copy, "--truth", truth, "--out", tmp_path / "b"))
    assert "identical samples" in msg
    # one bag topic as both
    from tests.bagfixtures import write_flight as write_bag_flight

    bag = write_bag_flight(tmp_path / "f.bag", "ros1", duration=15.0)
    msg = one_line_error(
        qsls("ingest", bag, "--vio-topic", "/mocap/pose", "--truth-topic", "/mocap/pose",
             "--out", tmp_path / "c")
    )  # fmt: skip
    assert "the VIO and truth streams are the same" in msg
    assert not any((tmp_path / n).exists() for n in "abc")


def test_a_text_stamp_out_of_order_is_an_error_naming_its_line(tmp_path):
    t = np.arange(0, 20, 0.02)
    rng = np.random.default_rng(0)
    vio = _circle(t) + rng.normal(scale=0.01, size=(len(t), 3))
    truth = _tum(tmp_path / "truth.tum", t, _circle(t))
    t_bad = t.copy()
    t_bad[500] -= 3.0  # three seconds early, on data line 501 = file line 502
    bad = _tum(tmp_path / "vio.tum", t_bad, vio)
    msg = one_line_error(qsls("ingest", "--vio", bad, "--truth", truth, "--out", tmp_path / "o"))
    assert "line 502" in msg and "2.98 s earlier" in msg  # than line 501 (t = 9.98 s)
    # two lines swapped (0.02 s, within the 0.1 s tolerance) are sorted and counted as before
    t_ok = t.copy()
    t_ok[500], t_ok[501] = t[501], t[500]
    ok = _tum(tmp_path / "ok.tum", t_ok, vio)
    proc = qsls("ingest", "--vio", ok, "--truth", truth, "--out", tmp_path / "ok")
    assert proc.returncode == 0, proc.stderr


def test_fit_refuses_a_zero_error_model_and_flights_of_different_dt(tmp_path):
    t, x = circle_states(0)
    same = write_flight(tmp_path / "same", t, x, x.copy())
    msg = one_line_error(qsls("fit", same, "--out", tmp_path / "fz", "--no-figures"))
    assert "zero error" in msg and "eps_e = S = 0" in msg

    flights, _ = vio_flights(tmp_path / "ok", n=1)
    t2, x2 = circle_states(1, dt=0.05)
    fast = write_flight(tmp_path / "fast", t2, x2, x2 + 0.01 * np.sin(x2))
    msg = one_line_error(qsls("fit", flights[0], fast, "--out", tmp_path / "fd", "--no-figures"))
    assert "different dt" in msg and "0.1 s" in msg and "0.05 s" in msg
    assert not (tmp_path / "fz").exists() and not (tmp_path / "fd").exists()


# --------------------------------------------------------------------------- smaller: topics
def test_topic_selection_pose_vio_tf_frames_and_a_too_strict_max_gap(tmp_path):
    from qsls.pipeline.ingest.sources.messages import PoseStream
    from qsls.pipeline.ingest.sources.msgtypes import POSE_STAMPED
    from qsls.pipeline.ingest.sources.write import write_bag
    from tests.bagfixtures import make_flight, tf_streams

    f = make_flight(duration=15.0, dropouts=())
    v = f.vio
    pose_vio = PoseStream("/vio/pose", v.header_ns, v.log_ns, v.position, v.orientation,
                          msgtype=POSE_STAMPED)  # fmt: skip
    bag = write_bag(tmp_path / "pose.bag", [pose_vio, f.truth], "ros1")
    proc = qsls("ingest", bag, "--out", tmp_path / "pose")
    assert proc.returncode == 0, proc.stderr
    assert "/vio/pose (PoseStamped" in proc.stdout
    # two pose topics, neither named as truth: why it cannot choose
    other = PoseStream("/slam/pose", v.header_ns, v.log_ns, v.position, v.orientation,
                       msgtype=POSE_STAMPED)  # fmt: skip
    bag2 = write_bag(tmp_path / "two.bag", [pose_vio, other, f.truth], "ros1")
    msg = one_line_error(qsls("ingest", bag2, "--out", tmp_path / "two"))
    assert "no nav_msgs/msg/Odometry topic" in msg and "/slam/pose" in msg

    tf1, tf2 = tf_streams(f.truth, "imu", f.truth.position * 0, 5)
    tf_bag = write_bag(tmp_path / "tf.bag", [f.vio, tf1, tf2], "ros1")
    msg = one_line_error(qsls("ingest", tf_bag, "--out", tmp_path / "tf"))
    assert "--truth-frame" in msg and "world/quad" in msg and "quad/imu" in msg

    t = f.truth
    k = slice(None, None, 60)  # 100 Hz -> 1.67 Hz
    slow = PoseStream("/mocap/pose", t.header_ns[k], t.log_ns[k], t.position[k], t.orientation[k],
                      msgtype=POSE_STAMPED)  # fmt: skip
    slow_bag = write_bag(tmp_path / "slow.bag", [f.vio, slow], "ros1")
    msg = one_line_error(qsls("ingest", slow_bag, "--out", tmp_path / "slow"))
    assert "1.67 Hz" in msg and "--max-gap 0.25" in msg and "every 0.6 s" in msg
    proc = qsls("ingest", slow_bag, "--out", tmp_path / "slow", "--max-gap", "1.5")
    assert proc.returncode == 0, proc.stderr
