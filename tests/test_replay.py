"""`qsls replay` on simulated bags: the commands in the MCAP (read back with rosbags) are what
the same controller commanded in flight, gaps are listed and restart the controller."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from qsls.pipeline.control.artifacts import load_runtime
from qsls.pipeline.ingest.sources.bags import BagSource
from qsls.pipeline.ingest.sources.messages import OdometryStream
from qsls.pipeline.ingest.sources.write import write_bag
from tests.test_export import _one_line_error, compiler, controllers, invoke  # noqa: F401

STATE = ["px", "py", "pz", "vx", "vy", "vz"]
MASS_G = 0.256 * 9.81


@pytest.fixture(scope="module")
def flown(tmp_path_factory, controllers):  # noqa: F811
    """A 12 s circle flown by the certified controller; the VIO frame is the world frame, so
    the replay (reference = the same circle) must command what the controller commanded."""
    root = tmp_path_factory.mktemp("replay")
    cfg = root / "sim.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "duration": 12.0,
                "seed": 4,
                "controller": {"kind": str(controllers["proper"])},
                # the position-only emulator: with its motion parts this seed's controller
                # samples a blur outlier (0.67 m/s) and commands 32 deg of roll, beyond the
                # tilt range checked below
                "vio": {"blur": False, "motion_drift": False, "feature_loss": False},
                "log": {
                    "format": "ros2-mcap",
                    "vio_frame_yaw_deg": 0.0,
                    "vio_frame_translation": [0.0, 0.0, 0.0],
                },
            }
        )
    )
    res = invoke("simulate", "--config", cfg, "--out", root / "sim")
    assert res.exit_code == 0, res.output
    return root, root / "sim" / "flight", pd.read_parquet(root / "sim" / "control.parquet")


def read_mcap(path):
    """Every message by topic, decoded with types built from the definitions in the file."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    out: dict[str, list] = {}
    with Reader(path) as r:
        for c in r.connections:
            ts.register(get_types_from_msg(c.msgdef.data, c.msgtype))
        types = {c.topic: c.msgtype for c in r.connections}
        for conn, t, raw in r.messages():
            out.setdefault(conn.topic, []).append((t, ts.deserialize_cdr(raw, conn.msgtype)))
    return types, out


def report_of(path):
    """The replay's report: the rosbag2 metadata record's custom_data (read with mcap)."""
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        (meta,) = [m for m in make_reader(fh).iter_metadata() if m.name == "rosbag2"]
    info = yaml.safe_load(meta.metadata["serialized_metadata"])
    return json.loads(info["custom_data"]["qsls_replay"])


def deviations(msgs):
    return np.array([t for t, _ in msgs]), np.array([m.data for _, m in msgs])


def absolute_at(path, stamp):
    cmd = read_mcap(path)[1]["/qsls/command"]
    (m,) = [m for t, m in cmd if t == stamp]
    return np.array([m.vector.x, m.vector.y, m.vector.z])


def test_commands_equal_the_flown_controllers(tmp_path, controllers, flown):  # noqa: F811
    _, bag, control = flown
    out = tmp_path / "replay.mcap"
    res = invoke(
        "replay", controllers["proper"], bag, "--vio-topic", "/vio/odometry",
        "--reference", "circle", "--align", "none", "--out", out,
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "ticks" in res.output and "largest tilt" in res.output
    types, msgs = read_mcap(out)
    assert types == {
        "/mavros/setpoint_raw/attitude": "mavros_msgs/msg/AttitudeTarget",
        "/qsls/deviation": "std_msgs/msg/Float64MultiArray",
        "/qsls/command": "geometry_msgs/msg/Vector3Stamped",
    }
    stamps, dev = deviations(msgs["/qsls/deviation"])
    cs = control["stamp_ns"].to_numpy()
    common, i, j = np.intersect1d(stamps, cs, return_indices=True)
    assert len(common) == len(cs) >= 119  # every tick of the flight is a tick of the replay
    u_flown = control[["u_pitch", "u_roll", "u_thrust"]].to_numpy()[j]
    absolute = np.array([[m.vector.x, m.vector.y, m.vector.z] for _, m in msgs["/qsls/command"]])
    np.testing.assert_allclose(absolute[i], u_flown, rtol=0, atol=1e-12)
    y_minus_r = (
        control[[f"y_{s}" for s in STATE]].to_numpy()
        - control[[f"r_{s}" for s in STATE]].to_numpy()
    )
    np.testing.assert_allclose(dev[i, :6], y_minus_r[j], rtol=0, atol=1e-12)
    # the deviation's u is what the verified Python realization gives on these y - r
    ctrl = load_runtime(controllers["proper"])
    u_python = np.array([ctrl.step(y) for y in dev[:, :6]])
    np.testing.assert_allclose(dev[:, 6:], u_python, rtol=0, atol=1e-12)
    # AttitudeTarget: the exact map of the flown command (force [-m g pitch, m g roll, thrust],
    # body z along it, yaw 0: the minimal tilt)
    att = msgs["/mavros/setpoint_raw/attitude"]
    for k, jj in zip(i, j, strict=True):
        t, m = att[k]
        assert t == stamps[k] == m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        ua = u_flown[list(j).index(jj)]
        f = np.array([-MASS_G * ua[0], MASS_G * ua[1], ua[2]])
        n = f / np.linalg.norm(f)
        q = np.array([-n[1], n[0], 0.0, 1 + n[2]]) / np.sqrt(2 * (1 + n[2]))
        got = [m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w]
        np.testing.assert_allclose(got, q, rtol=0, atol=1e-12)
        assert m.type_mask == 7
        assert m.thrust == pytest.approx(0.5 * np.linalg.norm(f) / MASS_G, rel=1e-6)
    # the limits in the report, recomputed from the commands
    lim = report_of(out)["limits"]
    f = np.c_[-MASS_G * absolute[:, 0], MASS_G * absolute[:, 1], absolute[:, 2]]
    tilt = np.degrees(np.arctan2(np.hypot(f[:, 0], f[:, 1]), f[:, 2]))
    assert lim["max_tilt_deg"] == pytest.approx(tilt.max(), abs=1e-9)
    assert lim["pct_tilt_exceeded"] == pytest.approx(100 * np.mean(tilt > 20.0))
    thrust = np.linalg.norm(f, axis=1)
    assert lim["thrust_max_ratio"] == pytest.approx(thrust.max() / MASS_G, rel=1e-12)
    assert lim["thrust_min_ratio"] == pytest.approx(thrust.min() / MASS_G, rel=1e-12)
    assert 0 < tilt.max() < 20 and report_of(out)["gaps"] == [] and lim["pct_limited"] == 0


def test_backends_agree_and_output_is_deterministic(tmp_path, controllers, flown, compiler):  # noqa: F811
    _, bag, _ = flown
    devs = {}
    for name, extra in (("a", []), ("b", []), ("c", ["--backend", "c"])):
        out = tmp_path / f"{name}.mcap"
        res = invoke(
            "replay", controllers["proper"], bag, "--reference", "circle", "--out", out, *extra
        )
        assert res.exit_code == 0, res.output
        devs[name] = deviations(read_mcap(out)[1]["/qsls/deviation"])[1]
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    assert np.abs(devs["a"] - devs["c"]).max() <= 1e-12


def test_gap_is_listed_and_restarts_the_controller(tmp_path, controllers, flown):  # noqa: F811
    _, bag, control = flown
    with BagSource(bag) as src:
        (vio,) = src.read_many([("/vio/odometry", None)])
    t0 = int(vio.header_ns[0])
    keep = ~((vio.header_ns >= t0 + 5_000_000_000) & (vio.header_ns < t0 + 5_600_000_000))
    stream = OdometryStream(
        topic="/vio/odometry",
        header_ns=vio.header_ns[keep],
        log_ns=vio.log_ns[keep],
        position=vio.position[keep],
        orientation=vio.orientation[keep],
        linear_velocity=vio.velocity[keep],
    )
    gapped = write_bag(tmp_path / "gapped.mcap", [stream], "mcap")
    out = tmp_path / "replay.mcap"
    res = invoke("replay", controllers["proper"], gapped, "--reference", "circle", "--out", out)
    assert res.exit_code == 0, res.output
    assert "warning: VIO gap of 0.610 s at 4.990 s" in res.output
    stamps, dev = deviations(read_mcap(out)[1]["/qsls/deviation"])
    gap_lo, gap_hi = t0 + 4_990_000_000, t0 + 5_600_000_000
    assert not np.any((stamps > gap_lo) & (stamps < gap_hi))
    assert len(stamps) == 121 - 6  # ticks 5.0 .. 5.5 s dropped
    before, after = stamps < gap_lo, stamps >= gap_hi
    # before the gap: the flown commands; after it: a controller started afresh
    u_cols = control[["u_pitch", "u_roll", "u_thrust"]].to_numpy()
    u_flown = dict(zip(control["stamp_ns"], u_cols, strict=True))
    ctrl = load_runtime(controllers["proper"])
    np.testing.assert_allclose(
        dev[before, 6:], [ctrl.step(y) for y in dev[before, :6]], rtol=0, atol=1e-12
    )
    ctrl.reset()
    np.testing.assert_allclose(
        dev[after, 6:], [ctrl.step(y) for y in dev[after, :6]], rtol=0, atol=1e-12
    )
    first = stamps[after][0]
    assert np.abs(absolute_at(out, first) - u_flown[first]).max() > 1e-3  # restarted: not as flown
    rep = report_of(out)
    assert rep["segments"] == 2 and len(rep["gaps"]) == 1
    assert rep["controller_reset_at_ns"] == [int(stamps[0]), int(first)]
    with Reader(out) as r:
        assert r.message_count == 3 * len(stamps)


def test_bad_input(tmp_path, controllers, flown):  # noqa: F811
    _, bag, _ = flown
    good, args = controllers["proper"], ["--reference", "circle"]
    (tmp_path / "old.mcap").write_bytes(b"keep me")
    res = invoke("replay", good, bag, *args, "--out", tmp_path / "old.mcap")
    _one_line_error(res, "already exists", "--force")
    assert (tmp_path / "old.mcap").read_bytes() == b"keep me"
    res = invoke("replay", controllers["nominal"], bag, *args, "--out", tmp_path / "n.mcap")
    _one_line_error(res, "uncertified", "--allow-uncertified")
    res = invoke("replay", good, bag, *args, "--out", tmp_path / "x.bag")
    _one_line_error(res, "*.mcap")
    res = invoke("replay", good, bag, "--reference", "spiral", "--out", tmp_path / "x.mcap")
    _one_line_error(res, "spiral")
    res = invoke("replay", good, bag, *args, "--vio-topic", "/nope", "--out", tmp_path / "x.mcap")
    _one_line_error(res, "/nope")
    res = invoke("replay", good, tmp_path / "none.bag", *args, "--out", tmp_path / "x.mcap")
    _one_line_error(res, "none.bag")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.mcap"]  # nothing half-written


def test_an_output_overlapping_an_input_is_refused_even_with_force(tmp_path, controllers, flown):  # noqa: F811
    """Issue 26, item 1: ``--out flight.mcap --force`` on the recorded flight itself used to
    replace it with the replay."""
    import hashlib
    import shutil

    _, bag, _ = flown
    (inner,) = sorted(bag.glob("*.mcap"))
    flight = tmp_path / "flight.mcap"
    shutil.copyfile(inner, flight)
    before = hashlib.sha256(flight.read_bytes()).hexdigest()
    good, args = controllers["proper"], ["--vio-topic", "/vio/odometry", "--reference", "circle"]
    res = invoke("replay", good, flight, *args, "--out", flight, "--force")
    msg = _one_line_error(res, "is the input", "even with --force")
    assert hashlib.sha256(flight.read_bytes()).hexdigest() == before
    # inside the rosbag2 folder that is the input, and inside the controller folder
    res = invoke("replay", good, bag, *args, "--out", bag / "replay.mcap", "--force")
    _one_line_error(res, "lies inside the input")
    res = invoke("replay", good, flight, *args, "--out", good / "replay.mcap", "--force")
    _one_line_error(res, "lies inside the input")
    assert not (bag / "replay.mcap").exists() and not (good / "replay.mcap").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight.mcap"], msg


def test_an_unwritable_output_is_one_line_for_export_and_replay(tmp_path, controllers, flown):  # noqa: F811
    """Issue 26, item 5: a read-only or impossible output location was a 40-line OSError."""
    from tests.test_new_user import _unwritable

    _, bag, _ = flown
    good = controllers["proper"]
    for out, folder, why in _unwritable(tmp_path):
        res = invoke("export", good, "--target", "python", "--out", out)
        _one_line_error(res, f"cannot write the output folder {out.absolute()}: ",
                        f"folder {folder} is not writable ({why})")  # fmt: skip
        res = invoke("replay", good, bag, "--reference", "circle", "--out", out / "r.mcap")
        _one_line_error(res, f"cannot write the output file {(out / 'r.mcap').absolute()}: ",
                        f"folder {folder} is not writable ({why})")  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_the_replay_is_the_same_bytes_wherever_the_recording_lives(tmp_path, controllers, flown):  # noqa: F811
    """Issue 26, item 4: the MCAP held the source's absolute path."""
    import shutil

    from qsls.pipeline.core.artifacts import sha256_path

    _, bag, _ = flown
    args = ["--vio-topic", "/vio/odometry", "--reference", "circle"]
    outs = []
    for where in ("here", "there/deeper"):
        copy = tmp_path / where / "flight"
        shutil.copytree(bag, copy)
        outs.append(tmp_path / where / "replay.mcap")
        res = invoke("replay", controllers["proper"], copy, *args, "--out", outs[-1])
        assert res.exit_code == 0, res.output
    assert outs[0].read_bytes() == outs[1].read_bytes()
    rep = report_of(outs[0])
    assert rep["source"] == rep["vio"]["source"] == "flight"
    assert rep["source_sha256"] == sha256_path(bag)
    assert str(tmp_path) not in outs[0].read_bytes().decode("latin-1")


def test_the_vio_frame_is_aligned_to_the_reference(tmp_path, controllers, flown):  # noqa: F811
    """Issue 26, item 14: the same flight logged with its VIO frame yawed 35 deg and shifted
    (the simulator's default) replays, aligned, as the flight logged in the world frame; not
    aligned, its first command is a large tilt, and the command says so loudly."""
    root, bag, _ = flown
    cfg = yaml.safe_load((root / "sim.yaml").read_text())
    cfg["log"] = {"format": "ros2-mcap"}  # the default VIO frame: 35 deg, (0.8, -0.4, 0.05) m
    (tmp_path / "sim.yaml").write_text(yaml.safe_dump(cfg))
    res = invoke("simulate", "--config", tmp_path / "sim.yaml", "--out", tmp_path / "sim")
    assert res.exit_code == 0, res.output
    turned = tmp_path / "sim" / "flight"
    args = [controllers["proper"], "--vio-topic", "/vio/odometry", "--reference", "circle"]
    devs, reps = {}, {}
    for name, src, extra in (
        ("world", bag, []),
        ("turned", turned, []),
        ("given", turned, ["--align", "none", "--vio-to-reference", "0.8,-0.4,0.05,35"]),
        ("none", turned, ["--align", "none"]),
    ):
        out = tmp_path / f"{name}.mcap"
        res = invoke("replay", args[0], src, *args[1:], *extra, "--out", out)
        assert res.exit_code == 0, res.output
        devs[name] = deviations(read_mcap(out)[1]["/qsls/deviation"])[1]
        reps[name] = report_of(out)
        assert ("WARNING: the first command tilts" in res.output) == (name == "none"), res.output
    # the 4-DoF fit is the same whatever frame the VIO was logged in
    np.testing.assert_allclose(devs["turned"], devs["world"], rtol=0, atol=1e-6)
    assert reps["turned"]["alignment"]["yaw_deg"] == pytest.approx(
        reps["world"]["alignment"]["yaw_deg"] + 35.0, abs=1e-6
    )
    # the known transform gives the world-frame flight's deviations without a fit
    plain = tmp_path / "plain.mcap"
    assert (
        invoke("replay", args[0], bag, *args[1:], "--align", "none", "--out", plain).exit_code == 0
    )
    plain_dev = deviations(read_mcap(plain)[1]["/qsls/deviation"])[1]
    np.testing.assert_allclose(devs["given"][:, :6], plain_dev[:, :6], rtol=0, atol=1e-9)
    # not aligned: far from the reference at the first tick, a large first tilt
    lim = reps["none"]["limits"]
    assert reps["none"]["first_deviation_m"] > 0.5 and lim["first_tilt_deg"] > 20
    assert reps["turned"]["first_deviation_m"] < 0.5
    assert reps["turned"]["limits"]["pct_tilt_exceeded"] < lim["pct_tilt_exceeded"]
    assert reps["none"]["warnings"] and not reps["turned"]["warnings"]


def test_the_report_lists_where_the_monitor_would_have_tripped(tmp_path, controllers, flown):  # noqa: F811
    """The monitor's ticks in the report are the ticks whose deviation exceeds a threshold of
    docs/monitor.md, recomputed here from the written deviations; a reference moved 1 m away
    (beyond every position threshold) trips on the first tick."""
    from qsls.pipeline.control.artifacts import load_controller_dir
    from qsls.pipeline.control.monitor import monitor_of

    _, bag, _ = flown
    spec = monitor_of(load_controller_dir(controllers["proper"]))
    thr = np.array(spec.threshold)
    assert spec.active and thr[:3].min() > 0.05 and thr[:3].max() < 1.0
    for center, name in (("[0,0]", "on"), ("[1,0]", "off")):
        out = tmp_path / f"{name}.mcap"
        res = invoke(
            "replay", controllers["proper"], bag, "--vio-topic", "/vio/odometry",
            "--reference", f"circle:center={center}", "--align", "none", "--out", out,
        )  # fmt: skip
        assert res.exit_code == 0, res.output
        stamps, dev = deviations(read_mcap(out)[1]["/qsls/deviation"])
        beyond = (np.abs(dev[:, :6]) > thr).any(axis=1)  # every channel trips (no beta)
        mon = report_of(out)["monitor"]
        assert mon["envelope_ticks"] == int(beyond.sum())
        assert mon["outlier_count_ticks"] == 0
        t = (stamps - stamps[0]) / 1e9
        if name == "off":
            assert mon["ticks_tripped"] == mon["envelope_ticks"]
            np.testing.assert_allclose(mon["trip_t_s"], t[beyond][:100], atol=1e-9)
            assert mon["first_trip_t_s"] == 0.0 and "premise broken" in res.output
        else:
            # on the reference the envelope is quiet; this flight's realized disturbance is 16
            # times the certificate's eps_w (0.159 against 0.01, from take-off), which the
            # innovation monitor (issue 48) may catch: its trips are said in words
            assert mon["envelope_ticks"] == 0
            assert mon["ticks_tripped"] == mon["innovation_ticks"]
            assert all(s.startswith("disturbance above eps_w on v") for s in mon["summary"])


def test_the_vios_own_uncertainty_is_shown_beside_the_monitor(tmp_path, controllers, flown):  # noqa: F811
    """Odometry covariances (issue 33): the replay's summary and report give the recorded
    position sigma (its largest axis), median and largest."""
    _, bag, _ = flown
    with BagSource(bag) as src:
        (vio,) = src.read_many([("/vio/odometry", None)])
    n = len(vio)
    pose_cov = np.zeros((n, 36))
    pose_cov[:, [0, 7, 14]] = np.column_stack([np.full(n, 1e-4), np.linspace(1e-4, 4e-4, n),
                                               np.full(n, 2e-4)])  # fmt: skip
    stream = OdometryStream(
        topic="/vio/odometry", header_ns=vio.header_ns, log_ns=vio.log_ns,
        position=vio.position, orientation=vio.orientation, linear_velocity=vio.velocity,
        pose_covariance=pose_cov,
    )  # fmt: skip
    out = tmp_path / "replay.mcap"
    src = write_bag(tmp_path / "cov.mcap", [stream], "mcap")
    res = invoke("replay", controllers["proper"], src, "--reference", "circle", "--out", out)
    assert res.exit_code == 0, res.output
    assert "VIO's own position sigma (m)" in res.output
    sigma = np.sqrt(np.maximum(np.linspace(1e-4, 4e-4, n), 2e-4))
    got = report_of(out)["vio_uncertainty"]["position_sigma_m"]
    assert got["max"] == pytest.approx(0.02) and got["median"] == pytest.approx(np.median(sigma))
