"""`qsls export`: C compiled by the system compiler and the stdlib module in an isolated Python
give the realization's u; the C flies the simulator like the Python one; bad input is refused.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.control.artifacts import load_runtime
from qsls.pipeline.core.artifacts import dump_yaml
from qsls.pipeline.errormodel.model import DisturbanceStats, ErrorModel, SlopeStats
from qsls.pipeline.export.cbuild import STRICT, CController, find_compiler
from qsls.pipeline.export.innovation import state_bytes
from tests.controllerfixtures import as_calibrated


def innovation_bytes(folder):
    """The innovation monitor's fields of the C state (docs/monitor.md)."""
    from qsls.pipeline.control.artifacts import load_controller_dir
    from qsls.pipeline.control.monitor import innovation_of

    return state_bytes(innovation_of(load_controller_dir(folder)), 8)


RUN = CliRunner()
T = 15
TICKS = 10_000
COMPILERS = [c for c in ("gcc", "clang") if shutil.which(c)]


def invoke(*args):
    return RUN.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def controllers(tmp_path_factory):
    """Real controllers from `qsls synth`: {"proper"|"strict": certified l1_robust, "nominal":
    the uncertified l1_nominal} (T = 15, the synth tests' error model)."""
    root = tmp_path_factory.mktemp("export")
    em = ErrorModel(
        disturbance=DisturbanceStats(max=0.01, source="inputs", n_steps=100),
        eps_e=0.05,
        eps_e_percentiles={"p95": 0.04},
        radius=1.0,
        # S = max and eps_e = max: the premise holds on all the training data (plainly certified)
        s_slope=SlopeStats(max=0.13, percentiles={"p50": 0.1, "p95": 0.12}),
        R0=0.05,
        delta=0.05,
        n_samples=100,
        n_pairs=1000,
    )
    (root / "fit").mkdir()
    (root / "fit" / "error_model.yaml").write_text(dump_yaml(em))
    base = ["synth", "--model", root / "fit", "-T", T, "--S", "max", "--controllers", "single"]
    runs = {
        "proper": ["--not-strictly-proper"],
        "strict": ["--strictly-proper"],
        "nominal": ["--no-robust"],
    }
    out = {}
    for key, extra in runs.items():
        res = invoke(*base, *extra, "--out", root / key)
        assert res.exit_code == 0, res.output
        (folder,) = [p for p in (root / key).iterdir() if p.is_dir() and p.name != "pd"]
        # synth alone says relaxed (not calibrated); export reads certified ones
        out[key] = folder if key == "nominal" else as_calibrated(folder)
    return out


@pytest.fixture(scope="module")
def compiler():
    cc = find_compiler()
    if cc is None:
        pytest.skip("no C compiler on this machine")
    return cc


def random_y(n=TICKS, seed=7):
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (n, 6))


def python_u(folder, ys):
    ctrl = load_runtime(folder)
    ctrl.reset()
    return np.array([ctrl.step(y) for y in ys])


def build(cc, export_dir, prefix="qsls_ctrl", opt="-O2"):
    """Compile the export with the strict flags into a shared library (the test's own call)."""
    lib = export_dir.parent / f"{export_dir.name}-{prefix}-{os.path.basename(cc)}.so"
    cmd = [cc, *STRICT, opt, "-fPIC", "-shared", "-o", lib, export_dir / f"{prefix}.c", "-lm"]
    res = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert res.stderr == ""  # not even a note
    return lib


@pytest.mark.parametrize("timing", ["proper", "strict"])
def test_c_equals_python_realization(tmp_path, controllers, compiler, timing):
    folder = controllers[timing]
    out = tmp_path / "c"
    res = invoke("export", folder, "--target", "c", "--out", out)
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "qsls_ctrl.c", "qsls_ctrl.h"]
    src = (out / "qsls_ctrl.c").read_text() + (out / "qsls_ctrl.h").read_text()
    includes = {line.split()[1] for line in src.splitlines() if line.startswith("#include")}
    assert includes == {'"qsls_ctrl.h"', "<stddef.h>", "<string.h>", "<math.h>"}
    assert "malloc" not in src and "printf" not in src
    cert = yaml.safe_load((folder / "certificate.yaml").read_text())
    hdr = (out / "qsls_ctrl.h").read_text()
    assert cert["controller_sha256"] in hdr and "status certified" in hdr
    flat = " ".join(line.lstrip(" *") for line in hdr.splitlines())  # wrapped comment
    assert f"gamma = eps + S rho* = {cert['gamma']:.6g}" in flat and f"T = {T} taps" in hdr
    assert "dt = 0.1 s, mass = 0.256 kg" in hdr
    ys = random_y()
    want = python_u(folder, ys)
    manifest = json.loads((out / "manifest.json").read_text())["results"]
    for cc in COMPILERS or [compiler]:
        lib = build(cc, out)
        c = CController(lib, dt=0.1)
        assert (
            c.size
            == manifest["state_bytes"]
            >= (T * 6 + (T + 1) * 6) * 8 + (2 + T + 5 + 1) * 4 + innovation_bytes(folder)
        )
        assert (
            c.size
            <= (T * 6 + (T + 1) * 6) * 8 + (2 + T + 5 + 1) * 4 + innovation_bytes(folder) + 16
        )
        got = np.array([c.step(y) for y in ys])
        assert np.abs(got - want).max() <= 1e-12, cc
        assert np.abs(want).max() > 1.0  # the test drives the controller hard
        c.reset()  # reset really zeroes the memory: the same sequence again
        np.testing.assert_array_equal(np.array([c.step(y) for y in ys[:50]]), got[:50])
    if timing == "strict":  # u[k] does not depend on y[k]
        c = CController(build(compiler, out), dt=0.1)
        u0 = c.step(np.full(6, 1e3))
        assert np.all(u0 == 0.0)
    assert manifest["verify"]["max_abs_diff"] <= 1e-12


def test_float_precision_deviation_is_reported_and_small(tmp_path, controllers, compiler):
    folder = controllers["proper"]
    res = invoke("export", folder, "-t", "c", "--precision", "float", "--out", tmp_path / "f")
    assert res.exit_code == 0, res.output
    assert "float vs double" in res.output
    r = json.loads((tmp_path / "f" / "manifest.json").read_text())["results"]
    base = (T * 6 + (T + 1) * 6) * 4 + (2 + T + 5 + 1) * 4
    from qsls.pipeline.control.artifacts import load_controller_dir
    from qsls.pipeline.control.monitor import innovation_of

    inn = state_bytes(innovation_of(load_controller_dir(folder)), 4)
    assert base + inn <= r["state_bytes"] < base + inn + 8  # the innovation monitor's fields
    lib = build(compiler, tmp_path / "f")
    cf = CController(lib, precision="float", dt=0.1)
    ys = random_y(2000)
    u_f = np.array([cf.step(y) for y in ys])
    u_d = python_u(folder, ys)
    dev = np.abs(u_f - u_d).max()
    assert 0 < dev < 1e-4 * np.abs(u_d).max()  # single precision, not double, and close
    fvd = r["float_vs_double"]
    assert 0 < fvd["max_abs_du_random"] < 1e-4 * r["verify"]["max_abs_u"]
    assert 0 < fvd["max_abs_dx_closed_loop"] < 1e-5


@pytest.mark.parametrize("timing", ["proper", "strict"])
def test_stdlib_module_in_isolated_python(tmp_path, controllers, timing):
    folder = controllers[timing]
    out = tmp_path / "py"
    res = invoke("export", folder, "--target", "python", "--out", out, "--prefix", "ctrl_mod")
    assert res.exit_code == 0, res.output
    ys = random_y()
    (tmp_path / "y.json").write_text(json.dumps(ys.tolist()))
    u_att, acc, yaw = attitude_inputs()
    (tmp_path / "att.json").write_text(
        json.dumps(
            [[u, a, w] for u, a, w in zip(u_att.tolist(), acc.tolist(), yaw.tolist(), strict=True)]
        )
    )
    driver = tmp_path / "drive.py"
    driver.write_text(
        textwrap.dedent(
            f"""
            import json, sys
            sys.path.insert(0, {str(out)!r})
            import ctrl_mod
            assert "numpy" not in sys.modules
            c = ctrl_mod.Controller()
            c.reset()
            ys = json.load(open({str(tmp_path / "y.json")!r}))
            us = [c.step(y) for y in ys]
            print(json.dumps({{"u": us, "dt": ctrl_mod.DT, "status": ctrl_mod.STATUS,
                              "att": [ctrl_mod.attitude(u, a, w) for u, a, w in
                                      json.load(open({str(tmp_path / "att.json")!r}))]}}))
            """
        )
    )
    proc = subprocess.run(
        [sys.executable, "-I", "-S", str(driver)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    assert got["dt"] == 0.1 and got["status"] == "certified"
    assert np.abs(np.array(got["u"]) - python_u(folder, ys)).max() <= 1e-12
    # the module's attitude() is the numpy helper's exact map, limits included
    from qsls.pipeline.export.attitude import thrust_attitude

    thrust, q = thrust_attitude(u_att, acc, 0.256, yaw=yaw)
    np.testing.assert_allclose([t for t, _ in got["att"]], thrust, rtol=0, atol=1e-13)
    np.testing.assert_allclose([qq for _, qq in got["att"]], q, rtol=0, atol=1e-15)


def attitude_inputs(n=400, seed=1):
    """``u``, reference accelerations and yaws, a quarter of them beyond the default limits."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-0.4, 0.4, (n, 3))
    acc = rng.uniform(-3.0, 3.0, (n, 3))
    acc[: n // 4] *= 4.0  # up to 12 m/s^2: beyond 30 deg of tilt and 2 m g
    return u, acc, rng.uniform(-np.pi, np.pi, n)


def test_attitude_helper_signs(tmp_path, controllers, compiler):
    """C helper = the numpy helper (limits and yaw included); a positive paper pitch tilts
    thrust toward -x (vx' = -g pitch), a positive roll toward +y; the hover thrust is m g."""
    from qsls.pipeline.core.rotations import quat_to_matrix
    from qsls.pipeline.export.attitude import thrust_attitude

    out = tmp_path / "c"
    assert invoke("export", controllers["proper"], "-t", "c", "--out", out).exit_code == 0
    c = CController(build(compiler, out), dt=0.1)
    thrust, q = c.attitude([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert thrust == pytest.approx(0.256 * 9.81, abs=1e-15)
    np.testing.assert_allclose(q, [0, 0, 0, 1], atol=0)
    b3 = quat_to_matrix(c.attitude([0.1, 0.0, 0.0], [0.0, 0.0, 0.0])[1])[:, 2]
    assert b3[0] < -0.09 and abs(b3[1]) < 1e-15
    b3 = quat_to_matrix(c.attitude([0.0, 0.1, 0.0], [0.0, 0.0, 0.0])[1])[:, 2]
    assert b3[1] > 0.09 and abs(b3[0]) < 1e-15
    # feedforward: a reference accelerating toward +x tilts the thrust toward +x
    b3 = quat_to_matrix(c.attitude([0.0, 0.0, 0.0], [2.0, 0.0, 0.0])[1])[:, 2]
    assert b3[0] > 0
    u, acc, yaw = attitude_inputs()
    got = [c.attitude(uk, ak, wk) for uk, ak, wk in zip(u, acc, yaw, strict=True)]
    t_ref, q_ref = thrust_attitude(u, acc, 0.256, yaw=yaw)
    np.testing.assert_allclose([t for t, _ in got], t_ref, rtol=0, atol=1e-13)
    np.testing.assert_allclose([qq for _, qq in got], q_ref, rtol=0, atol=1e-15)
    # the limits are the header's: an export with others commands other attitudes
    out2 = tmp_path / "c2"
    res = invoke("export", controllers["proper"], "-t", "c", "--out", out2,
                 "--tilt-limit-deg", "10", "--thrust-limits", "0.8,1.2")  # fmt: skip
    assert res.exit_code == 0, res.output
    header = (out2 / "qsls_ctrl.h").read_text()
    assert "QSLS_CTRL_MAX_TILT 0.17453292519943295 /* rad (10 deg) */" in header
    assert "tilt <= 10 deg, thrust in [0.8, 1.2] x m g" in header
    c2 = CController(build(compiler, out2), dt=0.1)
    from qsls.pipeline.export.attitude import AttitudeLimits

    t2, q2 = thrust_attitude(u, acc, 0.256, AttitudeLimits(10.0, 0.8, 1.2), yaw=yaw)
    got2 = [c2.attitude(uk, ak, wk) for uk, ak, wk in zip(u, acc, yaw, strict=True)]
    np.testing.assert_allclose([t for t, _ in got2], t2, rtol=0, atol=1e-13)
    np.testing.assert_allclose([qq for _, qq in got2], q2, rtol=0, atol=1e-15)


def test_attitude_is_the_exact_flatness_map_within_its_limits():
    """Issue 26, items 15-16, from first principles: body z along a + g e3, thrust
    m |a + g e3| (not the small-angle m (g + a_z)), the yaw about world z after the minimal
    tilt, and the limits clamp tilt and thrust."""
    from qsls.pipeline.core.rotations import quat_to_matrix
    from qsls.pipeline.export.attitude import AttitudeLimits, thrust_attitude

    m, g = 0.256, 9.81
    lim = AttitudeLimits(30.0, 0.5, 2.0)
    # the quickstart's 1.6 m/s^2 sideways: thrust m sqrt(g^2 + a^2), 1.3 % above m g
    thrust, q = thrust_attitude([0.0, 0.0, 0.0], [1.6, 0.0, 0.0], m, lim)
    assert thrust[0] == pytest.approx(m * np.hypot(g, 1.6), rel=1e-14)
    assert thrust[0] / (m * g) - 1 == pytest.approx(0.0132, abs=2e-4)
    z = quat_to_matrix(q[0])[:, 2]
    np.testing.assert_allclose(z, np.array([1.6, 0.0, g]) / np.hypot(1.6, g), atol=1e-15)
    # random demands within the limits: body z = f / |f|, thrust |f|, yaw about world z
    rng = np.random.default_rng(3)
    u = rng.uniform(-0.1, 0.1, (300, 3))
    acc = rng.uniform(-1.5, 1.5, (300, 3))
    yaw = rng.uniform(-np.pi, np.pi, 300)
    thrust, q = thrust_attitude(u, acc, m, lim, yaw=yaw)
    f = m * (acc + np.c_[-g * u[:, 0], g * u[:, 1], u[:, 2] / m] + [0.0, 0.0, g])
    np.testing.assert_allclose(thrust, np.linalg.norm(f, axis=1), rtol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    for k in range(300):
        R = quat_to_matrix(q[k])
        np.testing.assert_allclose(R[:, 2], f[k] / np.linalg.norm(f[k]), atol=1e-14)
        # Rz(-yaw) R is a pure tilt: no rotation about its own z (its quaternion's z is 0)
        c, s = np.cos(yaw[k]), np.sin(yaw[k])
        tilt = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) @ R
        assert abs(tilt[0, 1] - tilt[1, 0]) < 1e-14
    # beyond the limits: tilt at most 30 deg, thrust within [0.5, 2] m g, direction kept
    thrust, q = thrust_attitude(
        [[0.0, 0.0, 0.0]] * 3, [[20.0, 0, 0], [0, 0, 30.0], [0, 0, -20.0]], m, lim
    )
    z = np.array([quat_to_matrix(qq)[:, 2] for qq in q])
    assert np.degrees(np.arccos(z[0, 2])) == pytest.approx(30.0, abs=1e-12) and z[0, 0] > 0
    assert thrust[1] == pytest.approx(2.0 * m * g) and z[1] == pytest.approx([0, 0, 1])
    assert thrust[2] == pytest.approx(0.5 * m * g) and z[2] == pytest.approx([0, 0, 1])


@pytest.mark.parametrize("timing", ["proper", "strict"])
def test_closed_loop_c_flies_like_python(tmp_path, controllers, compiler, timing):
    """`qsls simulate` with the controller's backend python vs c: same flight within 1e-9 m."""
    traj = {}
    for backend in ("python", "c"):
        cfg = tmp_path / f"{backend}.yaml"
        cfg.write_text(
            yaml.safe_dump(
                {
                    "duration": 12.0,
                    "seed": 2,
                    "controller": {"kind": str(controllers[timing]), "backend": backend},
                }
            )
        )
        res = invoke("simulate", "--config", cfg, "--out", tmp_path / backend)
        assert res.exit_code == 0, res.output
        traj[backend] = pd.read_parquet(tmp_path / backend / "trajectory.parquet")
    cols = [c for c in traj["python"].columns if c.startswith("x_p")]
    assert len(cols) == 3 and len(traj["c"]) == len(traj["python"]) > 1000
    a, b = traj["python"][cols].to_numpy(), traj["c"][cols].to_numpy()
    assert np.abs(a - b).max() <= 1e-9
    assert np.ptp(a[:, 0]) > 1.0  # it flew the circle


def test_exports_are_deterministic_and_prefix_renames(tmp_path, controllers, compiler):
    folder = controllers["proper"]
    for d in ("a", "b"):
        args = ("export", folder, "-t", "c", "--prefix", "quad7", "--out", tmp_path / d)
        assert invoke(*args, "--verify-ticks", 10).exit_code == 0
    for name in ("quad7.c", "quad7.h"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    text = (tmp_path / "a" / "quad7.h").read_text()
    assert "int quad7_step(quad7_t *c" in text and "QUAD7_T 15" in text
    c = CController(build(compiler, tmp_path / "a", prefix="quad7"), "quad7", dt=0.1)
    ys = random_y(300)
    assert np.abs(np.array([c.step(y) for y in ys]) - python_u(folder, ys)).max() <= 1e-12


def _one_line_error(res, *words):
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    assert "Traceback" not in res.output
    for w in words:
        assert w in lines[0], lines[0]


def test_bad_input(tmp_path, controllers):
    good = controllers["proper"]
    nominal = controllers["nominal"]
    res = invoke("export", nominal, "-t", "c", "--out", tmp_path / "u")
    _one_line_error(res, "uncertified", "robustness_lhs", "--allow-uncertified")
    assert not (tmp_path / "u").exists()
    res = invoke("export", nominal, "-t", "c", "--out", tmp_path / "u", "--allow-uncertified")
    assert res.exit_code == 0, res.output
    first = (tmp_path / "u" / "qsls_ctrl.h").read_text().splitlines()[0]
    assert first.startswith(
        "/* NOT CERTIFIED (status uncertified, exported with --allow-uncertified"
    )
    assert "NO GUARANTEE; missing: robustness condition fails: robustness_lhs = " in first
    # a relaxed premise is not certified
    relaxed = tmp_path / "relaxed"
    shutil.copytree(good, relaxed)
    cert = yaml.safe_load((relaxed / "certificate.yaml").read_text())
    cert["status"] = "relaxed"
    (relaxed / "certificate.yaml").write_text(yaml.safe_dump(cert))
    res = invoke("export", relaxed, "-t", "python", "--out", tmp_path / "r")
    _one_line_error(res, "relaxed", "premise is relaxed", "not plainly certified")
    # tampered: one tap changed (the gains are rewritten to match, the sha256 does not)
    tampered = tmp_path / "tampered"
    shutil.copytree(good, tampered)
    from qsls.pipeline.control.artifacts import Controller

    ctrl = Controller.load(tampered)
    uy = ctrl.taps.Phi_uy.copy()
    uy[3, 0, 0] += 1e-6
    import dataclasses

    dataclasses.replace(ctrl, taps=dataclasses.replace(ctrl.taps, Phi_uy=uy)).save(tampered)
    res = invoke("export", tampered, "-t", "c", "--out", tmp_path / "t")
    _one_line_error(res, "is not the controller its certificate.yaml certifies")
    res = invoke("export", good, "-t", "fortran", "--out", tmp_path / "x")
    _one_line_error(res, "target", "fortran")
    res = invoke("export", good, "-t", "python", "--precision", "float", "--out", tmp_path / "x")
    _one_line_error(res, "float")
    res = invoke("export", good, "-t", "c", "--prefix", "9lives", "--out", tmp_path / "x")
    _one_line_error(res, "prefix")
    (tmp_path / "exists").mkdir()
    res = invoke("export", good, "-t", "c", "--out", tmp_path / "exists")
    _one_line_error(res, "already exists", "--force")
    assert list((tmp_path / "exists").iterdir()) == []
    res = invoke("export", good, "-t", "c", "--out", tmp_path / "exists", "--force")
    assert res.exit_code == 0, res.output
    # --force replaces only what qsls wrote: the user's files beside an export are refused
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("the user's")
    res = invoke("export", good, "-t", "c", "--out", tmp_path / "mine", "--force")
    _one_line_error(res, "holds files qsls did not write (notes.txt)")
    assert (tmp_path / "mine" / "notes.txt").read_text() == "the user's"
    (tmp_path / "exists" / "sub").mkdir()
    (tmp_path / "exists" / "sub" / "mine.c").write_text("int x;")
    res = invoke("export", good, "-t", "c", "--out", tmp_path / "exists", "--force")
    _one_line_error(res, "holds files qsls did not write (sub/mine.c)")
    assert (tmp_path / "exists" / "sub" / "mine.c").is_file()
    res = invoke("export", tmp_path / "nope", "-t", "c", "--out", tmp_path / "y")
    _one_line_error(res, "no such controller folder")
    pd_folder = good.parent / "pd"
    res = invoke("export", pd_folder, "-t", "c", "--out", tmp_path / "y", "--allow-uncertified")
    _one_line_error(res, "static gain")


@pytest.mark.slow
def test_evaluate_fly_flies_the_exported_c(tmp_path, compiler):
    """`qsls fly --backend c`: the same flights as the Python realization's."""
    steps = [
        ("simulate", "--duration", 10, "--seed", 0, "--out", tmp_path / "sim"),
        ("ingest", tmp_path / "sim" / "flight.bag", "--out", tmp_path / "ing"),
        ("fit", tmp_path / "ing", "--radius", 2, "--out", tmp_path / "fit"),
        ("synth", "--model", tmp_path / "fit", "-T", T, "--S", 0.05, "--delta", 0,
         "--controllers", "single", "--out", tmp_path / "syn"),
    ]  # fmt: skip
    for args in steps:
        res = invoke(*args)
        assert res.exit_code == 0, res.output
    (tmp_path / "ev.yaml").write_text("fly:\n  se3: false\n")
    flights = {}
    for backend in ("python", "c"):
        out = tmp_path / f"ev_{backend}"
        res = invoke(
            "fly", "--model", tmp_path / "fit", "--controller", tmp_path / "syn",
            "--seeds", 0, "--duration", 8, "--conditions", "regular", "--jobs", 1,
            "--no-figures", "--config", tmp_path / "ev.yaml", "--backend", backend, "--out", out,
        )  # fmt: skip
        assert res.exit_code == 0, res.output
        manifest = json.loads((out / "manifest.json").read_text())
        assert manifest["options"]["sim"]["controller"]["backend"] == backend
        flights[backend] = {
            p.name: pd.read_parquet(p / "flight.parquet") for p in (out / "flights").iterdir()
        }
    assert sorted(flights["c"]) == ["regular_s0_l1_robust", "regular_s0_pd"]
    for name, a in flights["c"].items():
        b = flights["python"][name]
        cols = [c for c in a.columns if c.startswith("x_p")]
        assert len(cols) == 3 and len(a) == len(b) > 50
        assert np.abs(a[cols].to_numpy() - b[cols].to_numpy()).max() <= 1e-9
