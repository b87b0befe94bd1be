"""The simulator: RotorPy dynamics reproduced, signs, integrator, tracking, controllers, crash."""

from __future__ import annotations

import numpy as np
import pytest
from rotorpy.vehicles.multirotor import Multirotor
from scipy.spatial.transform import Rotation

from qsls.pipeline.core.plant import GRAVITY, quadrotor_model
from qsls.pipeline.core.references import Reference, ReferenceOptions
from qsls.pipeline.sim.closedloop import FlightOptions, fly
from qsls.pipeline.sim.controllers import LinearController, PDController, make_controller
from qsls.pipeline.sim.vehicle import (
    Vehicle,
    VehicleOptions,
    ctatt_to_paper,
    paper_to_ctatt,
)


def _flight(**kw) -> FlightOptions:
    return FlightOptions.model_validate(kw)


@pytest.mark.parametrize("aero", [True, False])
def test_derivative_and_motor_command_match_rotorpy(aero):
    veh = Vehicle(VehicleOptions(aero=aero))
    rng = np.random.default_rng(0)
    for _ in range(100):
        s = np.zeros(20)
        s[0:6] = rng.normal(size=6)
        q = rng.normal(size=4)
        s[6:10] = 1.02 * q / np.linalg.norm(q)  # slightly off unit: both normalize the same
        s[10:13] = rng.normal(size=3) * 3
        s[13:16] = rng.normal(size=3) * 0.5
        s[16:20] = rng.uniform(1000, 2800, 4)
        cmd = rng.uniform(1000, 2800, 4)
        ours = veh.derivative(s, cmd)
        theirs = veh.multirotor._s_dot_fn(0.0, s, cmd)
        np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)
        qd = rng.normal(size=4)
        qd /= np.linalg.norm(qd)
        thrust = rng.uniform(1, 4)
        stock = veh.multirotor.get_cmd_motor_speeds(
            Multirotor._unpack_state(s), {"cmd_thrust": thrust, "cmd_q": qd}
        )
        np.testing.assert_allclose(
            veh.motor_command(s, thrust, qd),
            np.clip(stock, veh.speed_min, veh.speed_max),
            rtol=1e-12,
            atol=1e-9,
        )


def test_paper_to_ctatt_is_yzx_with_negated_angles():
    rng = np.random.default_rng(1)
    for _ in range(20):
        pitch, roll = rng.uniform(-0.6, 0.6, 2)
        thrust, q = paper_to_ctatt(np.array([pitch, roll, 2.0]))
        expect = Rotation.from_euler("ZYX", [0.0, -pitch, -roll]).as_quat()
        assert min(np.abs(q - expect).max(), np.abs(q + expect).max()) < 1e-12
        np.testing.assert_allclose(ctatt_to_paper(thrust, q), [pitch, roll, 2.0], atol=1e-12)


@pytest.mark.parametrize("axis,sign_row", [(0, -1.0), (1, +1.0)])
def test_constant_paper_attitude_command_gives_the_papers_acceleration_sign(axis, sign_row):
    """Paper: vx' = -g pitch, vy' = +g roll. Fly a constant command from hover for 0.6 s."""
    veh = Vehicle(VehicleOptions(aero=False))
    s = veh.hover_state(np.array([0.0, 0.0, 1.0]))
    angle = 0.05
    u = np.array([0.0, 0.0, veh.mass * GRAVITY / np.cos(angle)])
    u[axis] = angle
    thrust, q = veh.command(u)
    h, steps = 0.005, 120
    for _ in range(steps):
        s = veh.step(s, thrust, q, h)
    t = h * steps
    v = s[3 + axis]
    expected = sign_row * GRAVITY * angle  # the paper's B row
    # the attitude loop needs ~0.15 s to reach the angle: average acceleration a bit lower
    assert np.sign(v) == np.sign(expected)
    assert 0.7 * abs(expected) * t < abs(v) < 1.05 * abs(expected) * t
    assert abs(s[3 + (1 - axis)]) < 0.05 * abs(v)  # no cross-coupling
    assert abs(s[5]) < 0.05  # thrust compensates the tilt
    # and the linear model agrees on the direction
    b = quadrotor_model().B
    assert np.sign(b[3 + axis, axis]) == np.sign(expected)


def test_rk4_matches_solve_ivp_on_the_same_flight():
    """Fixed-step RK4 at 100 Hz vs RotorPy's Multirotor.step (solve_ivp every step)."""
    base = {"duration": 3.0, "controller": {"feedback": "truth"}}
    ours = fly(_flight(**base, vehicle={"physics_hz": 100}))
    tight = fly(
        _flight(**base, vehicle={"physics_hz": 100, "integrator": "solve_ivp", "ivp_rtol": 1e-9})
    )
    stock = fly(_flight(**base, vehicle={"physics_hz": 100, "integrator": "solve_ivp"}))
    assert np.abs(ours.x - tight.x).max() < 1e-5
    assert np.abs(stock.x - tight.x).max() < 1e-5
    assert np.abs(ours.x[:, :3] - stock.x[:, :3]).max() < 1e-5
    assert not ours.crashed


def test_se3_on_true_state_tracks_the_circle():
    opts = _flight(controller={"kind": "se3", "feedback": "truth"})
    log = fly(opts)
    assert not log.crashed
    ro = opts.reference
    assert (ro.radius, 1.0 / ro.period) == (1.0, 0.2)
    t = log.t_ns / 1e9
    circle = t >= ro.start_s
    err = np.linalg.norm(log.x[circle, :3] - log.ref[circle, :3], axis=1)
    rms = float(np.sqrt(np.mean(err**2)))
    assert rms < 0.05, rms
    assert log.metrics()["tracking_rms_m"] < 0.05
    # the vehicle really went around: it crossed all four quadrants at the circle's height
    p = log.x[circle]
    assert p[:, 0].min() < -0.9 and p[:, 0].max() > 0.9 and p[:, 1].min() < -0.9
    assert np.abs(p[:, 2] - 1.0).max() < 0.1


def test_pd_flies_on_vio_and_controller_sees_the_estimate():
    opts = _flight(controller={"kind": "pd"}, duration=8.0)
    log = fly(opts, seed=3)
    assert not log.crashed
    assert log.dt == pytest.approx(0.1)
    # the controller saw y = x + e (the newest VIO sample), never the truth
    t_vio = log.vio_t_ns
    idx = np.searchsorted(t_vio, log.ctrl_t_ns, side="right") - 1
    np.testing.assert_allclose(log.ctrl_y, log.vio_y[idx])
    assert np.abs(log.ctrl_y - log.x[np.searchsorted(log.t_ns, log.ctrl_t_ns)]).max() > 1e-3
    assert log.metrics()["tracking_rms_m"] < 0.25


class _PDRuntime:
    """A synthesized-controller runtime (docs/model.md#reference-and-feedforward: dt, reset, step(y - r) -> u)."""

    def __init__(self, K: np.ndarray, dt: float) -> None:
        self.K, self.dt = K, dt

    def reset(self) -> None:
        pass

    def step(self, y: np.ndarray) -> np.ndarray:
        return self.K @ y


def test_linear_controller_adds_hover_and_feedforward_like_pd():
    pd = make_controller(_flight(controller={"kind": "pd"}).controller, 0.256)
    assert isinstance(pd, PDController)
    lin = LinearController(_PDRuntime(pd.K, pd.dt), 0.256, "pd-as-linear")
    ref = Reference(ReferenceOptions())
    rng = np.random.default_rng(0)
    for t in (0.0, 6.3, 9.1):
        r = ref.sample(t)
        y = r.state + rng.normal(0, 0.1, 6)
        np.testing.assert_allclose(lin.command(t, y, None, r), pd.command(t, y, None, r))


def test_synthesized_controller_from_folder_flies(tmp_path):
    """A controller folder as qsls synth writes it, loaded with artifacts.load_runtime."""
    from qsls.pipeline.control.artifacts import load_runtime
    from qsls.pipeline.control.pdgain import PDGains
    from qsls.pipeline.control.synth import SynthOptions, pd_controller, resolve

    folder = tmp_path / "pd"
    folder.mkdir()
    built = pd_controller(resolve(SynthOptions(S=0.0, eps_e=0.05, radius=1.0)), PDGains(), 20, {})
    built.controller.save(folder)
    built.certificate.save(folder)
    runtime = load_runtime(folder)
    assert runtime.dt == pytest.approx(0.1)
    ctrl = make_controller(_flight(controller={"kind": str(folder)}).controller, 0.256)
    log = fly(_flight(duration=6.0), ctrl)
    ref_log = fly(_flight(duration=6.0, controller={"kind": "pd"}))
    np.testing.assert_allclose(log.x, ref_log.x, atol=1e-9)


def test_divergent_controller_ends_the_flight_with_a_reason():
    opts = _flight(controller={"kind": "pd", "pd": {"kp": [2, 2, -6], "kd": [2, 2, -3]}})
    log = fly(opts)
    assert log.crashed
    assert log.crash_reason and ("ground" in log.crash_reason or "diverged" in log.crash_reason)
    assert log.crash_time_s < opts.flight_duration()
    assert log.t_ns[-1] / 1e9 == pytest.approx(log.crash_time_s)
    assert log.metrics()["crashed"]


def test_fast_se3_equals_rotorpy_se3control():
    from qsls.pipeline.core.references import RefSample
    from qsls.pipeline.sim.controllers import SE3Controller
    from qsls.pipeline.sim.vehicle import quad_params

    fast = SE3Controller(quad_params(), 0.01)
    stock = SE3Controller(quad_params(), 0.01, backend="rotorpy")
    rng = np.random.default_rng(4)
    for _ in range(200):
        y = rng.normal(0, 0.5, 6)
        q = rng.normal(size=4) * 0.2 + np.array([0, 0, 0, 1.0])
        r = RefSample(p=rng.normal(0, 0.5, 3), v=rng.normal(0, 0.5, 3), a=rng.normal(0, 1, 3))
        np.testing.assert_allclose(
            fast.command(0.0, y, q, r), stock.command(0.0, y, q, r), atol=1e-12
        )


def test_state_interpolation_between_physics_steps():
    """VIO and mocap samples off the physics grid: Hermite position, linear velocity."""
    from qsls.pipeline.sim.closedloop import _interp
    from qsls.pipeline.sim.mocap import interpolate_truth

    w = 2 * np.pi * 0.2
    t_ns = np.arange(0, 2_000_000_001, 5_000_000, dtype=np.int64)
    t = t_ns / 1e9
    x = np.c_[np.cos(w * t), np.sin(w * t), 1 + 0 * t, -w * np.sin(w * t), w * np.cos(w * t), 0 * t]
    yaw = 0.3 * t
    q = np.c_[0 * t, 0 * t, np.sin(yaw / 2), np.cos(yaw / 2)]
    query = np.arange(0, 2_000_000_000, 33_333_333, dtype=np.int64)
    p, v, qq = interpolate_truth(t_ns, x, q, query)
    tq = query / 1e9
    assert np.abs(p[:, 0] - np.cos(w * tq)).max() < 1e-8
    assert np.abs(v[:, 1] - w * np.cos(w * tq)).max() < 1e-4
    assert np.abs(qq[:, 2] - np.sin(0.15 * tq)).max() < 1e-6
    # the closed loop's scalar version agrees
    s = np.zeros((len(t), 20))
    s[:, :6], s[:, 6:10] = x, q
    i, a = 7, 0.37
    xi, qi, _ = _interp(s[i], s[i + 1], a, 0.005)
    pv, vv, qv = interpolate_truth(t_ns, x, q, np.array([t_ns[i] + round(a * 5_000_000)]))
    np.testing.assert_allclose(xi, np.r_[pv[0], vv[0]], atol=1e-12)
    np.testing.assert_allclose(qi, qv[0], atol=1e-12)
