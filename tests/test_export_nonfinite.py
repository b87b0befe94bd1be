"""A measurement that is not finite, or beyond ``Y_MAX``, does not poison the exported controller
(issue 50, item 2): the step refuses it (the filter's memory unchanged, ``u = 0``, the
``INPUT_REFUSED`` bit latched until reset), the same in C double, C float and stdlib Python; the
attitude helper answers a non-finite input with hover, never NaN."""

from __future__ import annotations

import math

import numpy as np
import pytest

from qsls.pipeline.control.monitor import monitor_flags, monitor_of
from qsls.pipeline.core.plant import GRAVITY
from qsls.pipeline.export.bank import INPUT_REFUSED, Y_MAX
from qsls.pipeline.export.cbuild import CController, compile_shared, find_compiler
from qsls.pipeline.export.python import load_module
from qsls.pipeline.export.stage import ExportOptions, export
from tests.controllerfixtures import gated

V = 1.5
NAN, INF = math.nan, math.inf


@pytest.fixture(scope="module")
def rts(tmp_path_factory):
    """The gated certified controller exported once per target by `export()` and compiled once
    (strict flags): ``{"c": double, "cf": float, "py": stdlib Python}`` runtimes, the folder,
    the export results and the Python module."""
    if find_compiler() is None:
        pytest.skip("no C compiler on this machine")
    root = tmp_path_factory.mktemp("nonfinite")
    ctrl = gated(root / "l1_gated", radius=1.0)
    res = {}
    for key, opts in {
        "double": ExportOptions(target="c", verify_ticks=300),
        "float": ExportOptions(
            target="c", precision="float", verify_ticks=300, closed_loop_ticks=200
        ),
        "python": ExportOptions(target="python", verify_ticks=300),
    }.items():
        res[key] = export(ctrl.folder, opts, root / key)
    kw = dict(dt=0.1, name="l1_gated")
    lib_d = compile_shared(root / "double" / "qsls_ctrl.c", root / "d.so")
    lib_f = compile_shared(root / "float" / "qsls_ctrl.c", root / "f.so")
    mod = load_module((root / "python" / "qsls_ctrl.py").read_text())
    return {
        "c": CController(lib_d, **kw),
        "cf": CController(lib_f, precision="float", **kw),
        "py": mod.Controller(),
        "mod": mod,
        "ctrl": ctrl,
        "res": res,
        "root": root,
    }


def run(rt, ys):
    """``(u, flags)`` per tick from a reset; ``ys`` rows may hold None (Python only)."""
    rt.reset()
    us, fl = [], []
    for y in ys:
        us.append(np.asarray(rt.step(y), dtype=float))
        fl.append(rt.flags)
    return np.array(us), np.array(fl)


def quiet(n=60, seed=4):
    """Deviations well inside every threshold: no premise bit on any tick."""
    return np.random.default_rng(seed).uniform(-0.05, 0.05, (n, 6))


BAD = [
    (3, NAN),  # a velocity channel (before issue 50: an outlier, NaN u forever, bits 0)
    (0, NAN),  # a position channel (before: tripped once, then bits 0 with NaN u)
    (4, INF),
    (2, -INF),
    (1, 1e300),  # the float build read it as inf (before: NaN forever)
    (5, -1e300),
    (0, 1.0000001e6),  # beyond Y_MAX in double and in float (float32 1000000.125)
]


@pytest.mark.parametrize("where", range(len(BAD)))
def test_a_refused_measurement_leaves_the_state_and_latches_the_bit(rts, where):
    ch, value = BAD[where]
    ys = quiet()
    k = 17
    bad = ys.copy()
    bad = np.insert(bad, k, ys[k], axis=0)  # one more tick, refused
    bad[k, ch] = value
    for key in ("c", "cf", "py"):
        rt = rts[key]
        u0, f0 = run(rt, ys)
        u, f = run(rt, bad)
        assert (f0 == 0).all(), key
        # the refused tick: u = 0 exactly (+0.0), only the refusal bit
        assert f[k] == INPUT_REFUSED and np.array_equal(u[k], np.zeros(3)), (key, u[k])
        assert not np.signbit(u[k]).any()
        assert rt.refused == 1 and rt.trips == 0 and rt.first_trip is None, key
        # latched on every later tick, none before
        assert (f[:k] == 0).all() and (f[k + 1 :] == INPUT_REFUSED).all(), (key, f)
        # the filter's memory was left as it was: every other tick's u is bit for bit the u of
        # the same ticks without the refused one
        assert np.isfinite(u).all(), key
        assert np.array_equal(np.delete(u, k, axis=0), u0), key
        # reset clears the latch
        rt.reset()
        rt.step(ys[0])
        assert rt.flags == 0 and rt.refused == 0, key


def test_the_three_builds_refuse_the_same_ticks_and_python_refuses_none(rts):
    ys = quiet(120, seed=9).astype(object)
    ys_c = ys.astype(float)
    marks = {10: (3, NAN), 25: (0, INF), 40: (5, 1e300), 55: (1, 2e6), 70: (2, None)}
    for k, (ch, v) in marks.items():
        ys[k, ch] = v
        ys_c[k, ch] = NAN if v is None else v  # what a None reaches C as (CController)
    ys[90] = None  # the whole measurement missing: Python refuses it too
    ys_c[90, :] = NAN
    py_rows = [None if r[0] is None else list(r) for r in ys]
    # a None entry through CController is NaN: refused the same way
    u_n, f_n = run(rts["c"], py_rows[:80])
    u_py, f_py = run(rts["py"], py_rows)
    u_c, f_c = run(rts["c"], ys_c)
    u_f, f_f = run(rts["cf"], ys_c)
    assert np.array_equal(f_n, f_c[:80]) and np.array_equal(u_n, u_c[:80])
    refused = sorted([*marks, 90])
    for f in (f_py, f_c, f_f):
        np.testing.assert_array_equal(f, f_c)  # the same bits on every tick, all three
    assert (f_c[: refused[0]] == 0).all() and (f_c[refused[0] :] == INPUT_REFUSED).all()
    for u in (u_py, u_c, u_f):  # the refused ticks: bit for bit the same command, u = 0
        assert np.array_equal(u[refused], np.zeros((len(refused), 3)))
    assert rts["py"].refused == 6 and rts["c"].refused == 6 and rts["cf"].refused == 6
    ok = np.setdiff1d(np.arange(len(ys)), refused)
    assert np.abs(u_c[ok] - u_py[ok]).max() <= 1e-12
    assert 0 < np.abs(u_f[ok] - u_c[ok]).max() <= 1e-4  # float: close, not the double build


def test_the_bound_itself_is_accepted(rts):
    """``|y_i| = Y_MAX`` is a measurement (finite, read); beyond it is refused."""
    y = np.zeros(6)
    y[0] = Y_MAX
    for key in ("c", "cf", "py"):
        rt = rts[key]
        rt.reset()
        u = np.asarray(rt.step(y), dtype=float)
        assert not rt.flags & INPUT_REFUSED and rt.refused == 0, key
        assert np.isfinite(u).all()
        rt.step(-1.5 * y)
        assert rt.flags == INPUT_REFUSED, key


def test_premise_bits_after_a_refusal_and_the_outlier_window_stays_sound(rts):
    """A refused tick is not an outlier and moves the window on by one tick (so the count
    still covers the last T ticks); premise trips keep their bits beside the latched one."""
    spec = monitor_of(rts["ctrl"])
    ys = quiet(80, seed=2)
    for k in (20, 22, 24):  # m = 3 outliers: allowed
        ys[k, 3] = 5.0
    ys[23, 0] = NAN  # refused in between: counts as no outlier
    want = monitor_flags(spec, np.nan_to_num(ys), V)
    assert (want == 0).all()
    b = spec.threshold[1] + 0.5  # a position trip after the refusal
    ys[60, 1] = b
    for key in ("c", "cf", "py"):
        _, f = run(rts[key], ys)
        assert (f[:23] == 0).all() and f[23] == INPUT_REFUSED, key
        assert f[60] == INPUT_REFUSED | 1 and rts[key].first_trip == 60, key
        assert rts[key].trips == 1 and rts[key].refused == 1, key


def test_the_export_checks_its_own_refusal_and_the_header_says_what_to_do(rts):
    for key in ("double", "float", "python"):
        assert rts["res"][key].results["verify"]["refuses_nonfinite"] is True, key
    h = (rts["root"] / "double" / "qsls_ctrl.h").read_text()
    assert "#define QSLS_CTRL_INPUT_REFUSED 4" in h and "#define QSLS_CTRL_Y_MAX 1000000.0" in h
    flat = " ".join(line.strip(" *") for line in h.splitlines())
    assert "On INPUT_REFUSED the flight controller must stop flying this controller's u" in flat
    assert "switch to its fallback" in flat and "u = 0 (hover plus the reference's" in flat
    assert "unsigned int qsls_ctrl_refused(const qsls_ctrl_t *c);" in h
    doc = rts["mod"].__doc__
    assert "INPUT_REFUSED" in doc and "switch to its fallback" in " ".join(doc.split())
    assert rts["mod"].INPUT_REFUSED == INPUT_REFUSED and rts["mod"].Y_MAX == Y_MAX


HOVER_INPUTS = [
    ([NAN, 0.0, 0.0], [0.0, 0.0, 0.0], 0.3),
    ([0.0, INF, 0.0], [0.0, 0.0, 0.0], 0.3),
    ([0.0, 0.0, 0.0], [0.0, 0.0, -INF], 0.3),
    ([1e300, 0.0, 0.0], [0.0, 0.0, 0.0], 0.3),  # inf in the float build
    ([0.0, 0.0, 2e6], [0.0, 0.0, 0.0], 0.3),  # beyond Y_MAX
    ([0.0, 0.0, 0.0], [1e30, 0.0, 0.0], 0.3),  # would overflow f_x^2 in float
    ([0.1, 0.0, 0.0], [0.0, 0.0, 0.0], NAN),  # the yaw itself: level at yaw 0
]


@pytest.mark.parametrize("i", range(len(HOVER_INPUTS)))
def test_the_attitude_helper_answers_nonfinite_input_with_hover(rts, i):
    u, acc, yaw = HOVER_INPUTS[i]
    psi = yaw if math.isfinite(yaw) else 0.0
    q_level = [0.0, 0.0, math.sin(0.5 * psi), math.cos(0.5 * psi)]
    mass = rts["ctrl"].controller.mass
    for key, tol in (("c", 1e-15), ("cf", 1e-6), ("py", 1e-15)):
        att = rts["mod"].attitude if key == "py" else rts[key].attitude
        thrust, q = att(u, acc, yaw)
        assert math.isfinite(thrust) and np.isfinite(q).all(), (key, thrust, q)
        assert thrust == pytest.approx(mass * GRAVITY, rel=tol), key
        np.testing.assert_allclose(q, q_level, atol=tol)
    # Python: a None entry is not a number either
    thrust, q = rts["mod"].attitude([None, 0.0, 0.0], [0.0, 0.0, 0.0], None)
    assert thrust == mass * GRAVITY and q == [0.0, 0.0, 0.0, 1.0]


def test_the_attitude_of_finite_input_is_unchanged(rts):
    """The checks do not touch a finite command: the C and Python helpers still equal the
    numpy helper (limits and yaw included) on demands within and beyond the limits."""
    from qsls.pipeline.export.attitude import thrust_attitude

    rng = np.random.default_rng(1)
    u = rng.uniform(-0.4, 0.4, (100, 3))
    acc = rng.uniform(-12.0, 12.0, (100, 3))
    yaw = rng.uniform(-np.pi, np.pi, 100)
    mass = rts["ctrl"].controller.mass
    t_ref, q_ref = thrust_attitude(u, acc, mass, yaw=yaw)
    for att in (rts["c"].attitude, rts["mod"].attitude):
        got = [att(list(a), list(b), c) for a, b, c in zip(u, acc, yaw, strict=True)]
        np.testing.assert_allclose([t for t, _ in got], t_ref, rtol=0, atol=1e-13)
        np.testing.assert_allclose([list(q) for _, q in got], q_ref, rtol=0, atol=1e-15)
