"""The closed loop: vehicle, VIO emulator and controller, flown over a reference.

:func:`fly` is the one function that flies a controller; ``qsls simulate`` and the evaluate
stage both use it. Timing, all on integer nanoseconds of simulation time:

- physics steps of ``h = 1 / vehicle.physics_hz`` (RK4, attitude loop held over the step);
- the controller every ``dt`` (a whole number of physics steps), its command held until the
  next tick (zero-order hold, as in the paper's discrete model);
- VIO samples every ``1 / vio.rate_hz``; the true state at a sample time between two physics
  steps is interpolated (cubic Hermite position from the end velocities, linear velocity,
  normalized linear quaternion). The controller uses the newest sample at its tick:
  ``y = x + e`` with ``e`` from :class:`~qsls.pipeline.sim.vio.VioEmulator`, which also gets
  the true body rate there and the physics step's mean acceleration ``(v_{i+1} - v_i) / h``
  (for its motion-dependent parts: blur, drift with motion, feature loss).

With ``vio.kind: camera`` the estimate comes instead from the camera loop
(:class:`~qsls.pipeline.sim.camera.loop.CameraVio`): every physics step makes an IMU sample
that propagates an MSCKF, every ``1 / vio.camera.rate_hz`` a frame is rendered from the true
pose and tracked, and a VIO sample is the filter's latest estimate (``e = estimate - x``,
and the estimated attitude in ``vio_q_est``). The camera must see a textured plane from the
start pose (checked before flying).

A fault (``vio.fault``) adds a step ``bias`` to the error of every VIO sample from
``start_s`` on (the logged ``vio_e`` includes it).

The PX4 stand-in (``px4``, :mod:`qsls.pipeline.sim.px4`, docs/simulation.md#the-px4-stand-in):

- with ``px4.interface: px4`` the controller's input goes through the export's attitude map
  to PX4's attitude setpoint (an attitude and a normalized thrust, logged in
  ``ctrl_sp``), which the vehicle flies (:meth:`Vehicle.command_px4`);
- with the PX4 interface, or any estimator latency, jitter or drop, each VIO sample arrives
  at ``ceil((t + latency + jitter) / 1 us)`` (in order; some never, the first, the initial
  state, at ``t = 0``), and the controller reads the newest sample that has arrived at its
  tick (a whole number of µs). Without latency, jitter or drops that is the newest sample
  captured at or before the tick, as without the stand-in.

The flight's conditions the controller is not told (docs/calibration.md#conditions-as-a-stated-family):
the wind (``wind``, :mod:`qsls.pipeline.sim.wind`) is written into the state's wind slot
before each physics step, as RotorPy's ``simulate`` does, and a battery's sag
(``vehicle.sag``) scales the commanded rotor speeds of the step starting at ``t`` by
``sqrt(1 - sag t / duration)``.

A crash (position below ``crash.floor_z``, farther than ``crash.max_deviation`` from the
reference in any axis, tilt beyond ``crash.max_tilt_deg``, or a non-finite state) ends the
flight: the log holds everything up to it and says why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.core.references import Reference, RefSample
from qsls.pipeline.core.units import NS
from qsls.pipeline.sim.controllers import PositionController, make_controller
from qsls.pipeline.sim.options import CrashOptions, FlightOptions
from qsls.pipeline.sim.px4 import US, Px4Interface, arrivals
from qsls.pipeline.sim.vehicle import Vehicle
from qsls.pipeline.sim.vio import VioEmulator
from qsls.pipeline.sim.wind import wind_series

if TYPE_CHECKING:
    from qsls.pipeline.sim.camera.loop import CameraVio


@dataclass(frozen=True)
class FlightLog:
    """Arrays of one flight (simulation time in ns from 0; world = motion-capture frame)."""

    controller: str
    dt: float
    mass: float
    t_ns: np.ndarray  # (n,) physics steps
    x: np.ndarray  # (n, 6) true [p, v]
    q: np.ndarray  # (n, 4) true attitude xyzw
    w: np.ndarray  # (n, 3) true body rates
    ref: np.ndarray  # (n, 6) reference state at the physics steps
    vio_t_ns: np.ndarray  # (m,) VIO sample times
    vio_x: np.ndarray  # (m, 6) true state at the VIO samples
    vio_e: np.ndarray  # (m, 6) emulator error: y = x + e
    vio_q: np.ndarray  # (m, 4) attitude at the VIO samples
    vio_w: np.ndarray  # (m, 3) body rates at the VIO samples
    ctrl_t_ns: np.ndarray  # (k,) controller ticks
    ctrl_y: np.ndarray  # (k, 6) what the controller saw
    ctrl_ref: np.ndarray  # (k, 6) reference state
    ctrl_u: np.ndarray  # (k, 3) absolute [pitch, roll, thrust], paper signs
    crashed: bool = False
    crash_reason: str | None = None
    crash_time_s: float | None = None
    lipschitz: float | None = None
    """The emulator's bias-field Lipschitz constant (the true S-slope); None for the camera
    loop, whose errors come from no designed field."""
    emulator: dict[str, Any] = field(default_factory=dict)
    vio_q_est: np.ndarray | None = None  # (m, 4) estimated attitude (camera loop only)
    camera_frame: dict[str, np.ndarray] | None = None
    """The camera loop's kept frame and its tracked features (``Snapshot.arrays``), if any."""
    ctrl_acc: np.ndarray | None = None  # (k, 3) reference acceleration at the ticks
    ctrl_uff: np.ndarray | None = None
    """(k, 3) the feedforward the controller added at each tick (``RefSample.uff``)."""
    ctrl_sp: np.ndarray | None = None
    """(k, 5) PX4's attitude setpoint at each tick, ``[T, qx, qy, qz, qw]`` (normalized
    thrust; attitude of the z-up body in the z-up world): the PX4 interface only."""
    vio_arrival_us: np.ndarray | None = None
    """(m,) when each VIO sample reached the controller (µs of simulation time), where
    samples are read by arrival (:attr:`Px4Options.timed`)."""
    vio_dropped: np.ndarray | None = None
    """(m,) the VIO samples that never arrived (same condition)."""
    controller_mass: float | None = None
    """The mass the controller and the interface assumed, where it is not :attr:`mass`."""

    @property
    def vio_y(self) -> np.ndarray:
        """The VIO estimate ``y = x + e`` (m, 6) in the world frame."""
        return self.vio_x + self.vio_e

    @property
    def duration_s(self) -> float:
        return float(self.t_ns[-1]) / NS if len(self.t_ns) else 0.0

    def metrics(self) -> dict[str, Any]:
        """Tracking (true position vs reference, 2-norm) and perception error (inf norm)."""
        dp = np.linalg.norm(self.x[:, :3] - self.ref[:, :3], axis=1)
        en = np.abs(self.vio_e).max(axis=1) if len(self.vio_e) else np.zeros(1)
        du = np.diff(self.ctrl_u, axis=0) if len(self.ctrl_u) > 1 else np.zeros((1, 3))
        hover = np.array([0.0, 0.0, self.mass * 9.81])
        return {
            "duration_s": self.duration_s,
            "tracking_rms_m": float(np.sqrt(np.mean(dp**2))),
            "tracking_max_m": float(dp.max()),
            "perception_error_rms": float(np.sqrt(np.mean(en**2))),
            "perception_error_max": float(en.max()),
            "position_error_rms_m": float(np.sqrt(np.mean(self.vio_e[:, :3] ** 2)))
            if len(self.vio_e)
            else 0.0,
            "control_effort_rms": float(np.sqrt(np.mean((self.ctrl_u - hover) ** 2))),
            "control_smoothness_rms": float(np.sqrt(np.mean(du**2))),
            "crashed": self.crashed,
            "crash_reason": self.crash_reason,
        }


def _interp(s0: np.ndarray, s1: np.ndarray, a: float, h: float) -> tuple[np.ndarray, ...]:
    """State between two physics steps at fraction ``a``: (p, v) Hermite/linear, q nlerp, w.

    ``p = h00 p0 + h10 h v0 + h01 p1 + h11 h v1``, ``v = v0 + a (v1 - v0)``, ``q`` the
    normalized ``q0 + a (q1 - q0)`` (``q1`` on ``q0``'s side), ``w`` linear: plain floats in
    the order the array expressions summed them; the quaternion dots stay numpy's."""
    if a >= 1.0:
        return s1[0:6].copy(), s1[6:10].copy(), s1[10:13].copy()
    a2, a3 = a * a, a * a * a
    h00, h10, h01, h11 = 2 * a3 - 3 * a2 + 1, a3 - 2 * a2 + a, -2 * a3 + 3 * a2, a3 - a2
    h10h, h11h = h10 * h, h11 * h
    x0, x1 = s0.tolist(), s1.tolist()
    p = [h00 * x0[i] + h10h * x0[i + 3] + h01 * x1[i] + h11h * x1[i + 3] for i in range(3)]
    v = [x0[i] + a * (x1[i] - x0[i]) for i in range(3, 6)]
    q1 = s1[6:10] if s0[6:10] @ s1[6:10] >= 0 else -s1[6:10]
    q = s0[6:10] + a * (q1 - s0[6:10])
    q /= np.sqrt(q @ q)
    w = [x0[i] + a * (x1[i] - x0[i]) for i in range(10, 13)]
    return np.array(p + v), q, np.array(w)


_ESTIMATOR_STREAM = 2000
"""SeedSequence stream of the estimate's transport (jitter, drops); the VIO and the logs use
their own."""


def _ticks(period_s: float, h_ns: int, what: str) -> int:
    """Physics steps per period; the period must be a whole number of steps."""
    n = period_s * NS / h_ns
    k = round(n)
    if k < 1 or abs(n - k) > 1e-6:
        raise ConfigError(
            f"{what} period {period_s:g} s is not a whole number of physics steps "
            f"({h_ns / NS:g} s); choose vehicle.physics_hz as a multiple of the control rate"
        )
    return int(k)


@dataclass
class _Record:
    """What a flight records, allocated once: vehicle states ``S`` (one row per physics step),
    VIO samples and controller ticks."""

    S: np.ndarray
    vio_t: np.ndarray
    vio_x: np.ndarray
    vio_q: np.ndarray
    vio_w: np.ndarray
    vio_e: np.ndarray
    vio_qe: np.ndarray
    vio_a: np.ndarray
    """The physics step's mean acceleration at each sample (the emulator's input; not logged)."""
    c_t: np.ndarray
    c_y: np.ndarray
    c_r: np.ndarray
    c_u: np.ndarray
    c_a: np.ndarray
    c_sp: np.ndarray
    c_ff: np.ndarray

    @classmethod
    def allocate(cls, n_steps: int, n_vio: int, n_ctrl: int) -> _Record:
        return cls(
            S=np.empty((n_steps + 1, 20)),
            vio_t=np.empty(n_vio, dtype=np.int64),
            vio_x=np.empty((n_vio, 6)),
            vio_q=np.empty((n_vio, 4)),
            vio_w=np.empty((n_vio, 3)),
            vio_e=np.empty((n_vio, 6)),
            vio_qe=np.empty((n_vio, 4)),
            vio_a=np.empty((n_vio, 3)),
            c_t=np.empty(n_ctrl, dtype=np.int64),
            c_y=np.empty((n_ctrl, 6)),
            c_r=np.empty((n_ctrl, 6)),
            c_u=np.empty((n_ctrl, 3)),
            c_a=np.empty((n_ctrl, 3)),
            c_sp=np.empty((n_ctrl, 5)),
            c_ff=np.empty((n_ctrl, 3)),
        )

    def log(
        self, ctrl: PositionController, veh: Vehicle, t_ns: np.ndarray,
        ref_states: np.ndarray, n: int, m: int, k: int, *,
        crashed: bool, reason: str | None, crash_t: float | None,
        lipschitz: float | None, described: dict[str, Any], camera: bool,
        camera_frame: dict[str, np.ndarray] | None = None,
        px4: bool = False, arrival: tuple[np.ndarray, np.ndarray] | None = None,
        controller_mass: float | None = None,
    ) -> FlightLog:  # fmt: skip
        """The first ``n`` physics steps, ``m`` VIO samples and ``k`` controller ticks."""
        S = self.S[:n]
        return FlightLog(
            controller=ctrl.name,
            dt=float(ctrl.dt),
            mass=veh.mass,
            t_ns=t_ns,
            x=S[:, 0:6].copy(),
            q=S[:, 6:10].copy(),
            w=S[:, 10:13].copy(),
            ref=ref_states,
            vio_t_ns=self.vio_t[:m].copy(),
            vio_x=self.vio_x[:m].copy(),
            vio_e=self.vio_e[:m].copy(),
            vio_q=self.vio_q[:m].copy(),
            vio_w=self.vio_w[:m].copy(),
            ctrl_t_ns=self.c_t[:k].copy(),
            ctrl_y=self.c_y[:k].copy(),
            ctrl_ref=self.c_r[:k].copy(),
            ctrl_u=self.c_u[:k].copy(),
            crashed=crashed,
            crash_reason=reason,
            crash_time_s=crash_t,
            lipschitz=lipschitz,
            emulator=described,
            vio_q_est=self.vio_qe[:m].copy() if camera else None,
            camera_frame=camera_frame,
            ctrl_acc=self.c_a[:k].copy(),
            ctrl_uff=self.c_ff[:k].copy(),
            ctrl_sp=self.c_sp[:k].copy() if px4 else None,
            vio_arrival_us=arrival[0][:m].copy() if arrival is not None else None,
            vio_dropped=arrival[1][:m].copy() if arrival is not None else None,
            controller_mass=controller_mass,
        )


def fly(
    options: FlightOptions,
    controller: PositionController | None = None,
    seed: int | None = None,
    *,
    vehicle: Vehicle | None = None,
    progress: Progress = NULL_PROGRESS,
    stepwise: bool = False,
) -> FlightLog:
    """Fly ``controller`` (default: ``options.controller``) over the reference; see module doc.

    The camera loop's small matrices run on one BLAS thread (threads only add overhead
    there, and several flights run side by side on a process pool). ``stepwise`` flies the
    straightforward way, the same bits slower (the tests' and benchmarks' reference): the
    vehicle in whole-array numpy (:meth:`Vehicle.step_numpy`) and the emulator called once
    per VIO sample instead of once per controller tick for the samples since the last one."""
    if options.vio.kind != "camera":
        return _fly(options, controller, seed, vehicle=vehicle, progress=progress,
                    stepwise=stepwise)  # fmt: skip
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        return _fly(options, controller, seed, vehicle=vehicle, progress=progress,
                    stepwise=stepwise)  # fmt: skip


def _fly(
    options: FlightOptions,
    controller: PositionController | None = None,
    seed: int | None = None,
    *,
    vehicle: Vehicle | None = None,
    progress: Progress = NULL_PROGRESS,
    stepwise: bool = False,
) -> FlightLog:
    """Fly ``controller`` (default: ``options.controller``) over the reference; see module doc.

    The loop alone: its setup, each controller tick and the result are :class:`_Flight`'s; the
    physics step and the VIO sampling stay here, on locals (they run every physics step)."""
    f = _Flight.prepare(options, controller, seed, vehicle, stepwise)
    rec, cam, ref_p, crash, cos_tilt = f.rec, f.cam, f.ref_p, f.crash, f.cos_tilt
    S, vio_t, vio_x, vio_q, vio_w = rec.S, rec.vio_t, rec.vio_x, rec.vio_q, rec.vio_w
    vio_a = rec.vio_a
    h, h_ns, n_sub, vio_ns, n_vio_max = f.h, f.h_ns, f.n_sub, f.vio_ns, f.n_vio_max
    step, wind, sag, batch = f.step, f.wind, f.sag, f.batch
    s, y_latest = f.start()
    m = pending = 1  # samples so far; the first whose error is not made yet (batched emulator)
    next_vio = vio_ns
    end: tuple[str, float, int] | None = None  # why the flight ended early, when, its last step
    thrust, cmd_q = 0.0, np.array([0.0, 0.0, 0.0, 1.0])
    k = 0
    progress.start("flying", total=f.n_ctrl)
    for i in range(f.n_steps):
        if i % n_sub == 0:
            if batch and pending < m:
                y_latest, pending = f.flush(pending, m), m
            command = f.tick(i, k, s, y_latest, m)
            if command is None:
                end = ("controller output is not finite", i * h, i)
                break
            thrust, cmd_q = command
            k += 1
            progress.advance(1)
        s_next = step(s, thrust, cmd_q, h, math.sqrt(1.0 - sag * i * h) if sag else 1.0)
        if wind is not None:  # the wind held over the next step, at that step's start
            s_next[13:16] = wind[i + 1]
        S[i + 1] = s_next
        if cam is not None:
            cam.step(s, s_next)
        t1 = (i + 1) * h_ns
        while next_vio <= t1 and m < n_vio_max:
            xv, qv, wv = _interp(s, s_next, (next_vio - i * h_ns) / h_ns, h)
            vio_t[m], vio_x[m], vio_q[m], vio_w[m] = next_vio, xv, qv, wv
            if batch:
                vio_a[m] = (s_next[3:6] - s[3:6]) / h
            else:
                y_latest = f.sample(m, xv, wv, s, s_next, next_vio)
            m += 1
            next_vio += vio_ns
        s = s_next
        if (why := _crash_reason(s, ref_p[i + 1], (i + 1) * h, crash, cos_tilt)) is not None:
            end = (why, (i + 1) * h, i + 1)
            break
    progress.finish()
    if batch and pending < m:
        f.flush(pending, m)
    return f.log(m, k, end)


@dataclass
class _Flight:
    """One flight's fixed parts (clock, controller, emulator, reference arrays, VIO arrivals)
    and its records, set up by :meth:`prepare`; :func:`_fly` runs the loop over them.

    The emulator's errors are needed only when the controller reads ``y``: the samples since
    the previous tick are kept (state, body rate, acceleration) and their errors made in one
    :meth:`VioEmulator.errors` call (:meth:`flush`), which equals calling
    :meth:`VioEmulator.sample` on each in order (same random draws, same additions;
    tests/test_sim_vio.py)."""

    options: FlightOptions
    seed: int
    ctrl: PositionController
    veh: Vehicle
    m_ctrl: float
    iface: Px4Interface | None
    vio: VioEmulator
    cam: CameraVio | None
    h_ns: int
    n_sub: int
    n_ctrl: int
    arrival: tuple[np.ndarray, np.ndarray] | None
    t_ns: np.ndarray
    rec: _Record
    ref_p: np.ndarray
    ref_v: np.ndarray
    ref_a: np.ndarray
    ref_ff: np.ndarray
    stepwise: bool
    read: int = 0
    """The VIO sample the controller reads (by arrival)."""
    cursor: int = 0
    """The last VIO sample looked at (by arrival)."""

    @classmethod
    def prepare(
        cls, options: FlightOptions, controller: PositionController | None, seed: int | None,
        vehicle: Vehicle | None, stepwise: bool,
    ) -> _Flight:  # fmt: skip
        """The flight's parts, its clock checked (whole physics steps per tick, whole µs)."""
        seed = options.seed if seed is None else int(seed)
        veh = vehicle or Vehicle(options.vehicle)
        px4 = options.px4
        m_ctrl = veh.mass if px4.controller_mass is None else float(px4.controller_mass)
        ctrl = controller or make_controller(options.controller, m_ctrl)
        m_ctrl = float(getattr(ctrl, "mass", m_ctrl))
        iface = Px4Interface(px4, m_ctrl) if px4.interface == "px4" else None
        ref = Reference(options.reference)
        vio = VioEmulator(options.vio, seed)
        cam = _camera_loop(options, seed, veh) if options.vio.kind == "camera" else None
        h_ns = round(NS / options.vehicle.physics_hz)
        n_sub = _ticks(ctrl.dt, h_ns, "control")
        duration = options.flight_duration()
        n_ctrl = int(np.floor(duration / ctrl.dt + 1e-9))
        if n_ctrl < 1:
            raise ConfigError(
                f"duration {duration:g} s is shorter than one control period ({ctrl.dt:g} s)"
            )
        n_steps = n_ctrl * n_sub
        vio_ns = round(NS / options.vio.rate_hz)
        n_vio_max = n_steps * h_ns // vio_ns + 1
        arrival = _vio_arrivals(options, seed, n_sub * h_ns, n_vio_max, vio_ns)
        t_ns = np.arange(n_steps + 1, dtype=np.int64) * h_ns
        rec = _Record.allocate(n_steps, n_vio_max, n_ctrl)
        ref_p, ref_v, ref_a = ref.arrays(t_ns / NS)
        # the feedforward of each tick, for the controller's own mass and plant
        # (docs/guarantee.md, Disturbance in deviation coordinates)
        ref_ff = ref.feedforward(
            np.arange(n_ctrl) * (n_sub * h_ns / NS), n_sub * h_ns / NS,
            float(getattr(ctrl, "mass", veh.mass)), getattr(ctrl, "plant", "hover"),
        )  # fmt: skip
        return cls(
            options, seed, ctrl, veh, m_ctrl, iface, vio, cam, h_ns, n_sub, n_ctrl, arrival,
            t_ns, rec, ref_p, ref_v, ref_a, ref_ff, stepwise,
        )  # fmt: skip

    def __post_init__(self) -> None:
        o = self.options
        self.h = self.h_ns / NS
        self.n_steps = self.n_ctrl * self.n_sub
        self.vio_ns = round(NS / o.vio.rate_hz)
        self.n_vio_max = len(self.rec.vio_t)
        self.crash = o.crash
        self.cos_tilt = np.cos(np.radians(o.crash.max_tilt_deg))
        self.truth_feedback = o.controller.feedback == "truth"
        self.fault = np.asarray(o.vio.fault.bias, float) if o.vio.fault is not None else None
        self.fault_ns = round(o.vio.fault.start_s * NS) if o.vio.fault is not None else 0
        self.arrival_ns, self.dropped = np.zeros(0, dtype=np.int64), []
        if self.arrival is not None:
            self.arrival_ns, self.dropped = self.arrival[0] * US, self.arrival[1].tolist()
        self.step = self.veh.step_numpy if self.stepwise else self.veh.step
        self.batch = self.cam is None and not self.stepwise
        self.wind = wind_series(o.wind, self.seed, self.t_ns / NS)  # None in still air
        self.sag = float(o.vehicle.sag) / o.flight_duration()

    def start(self) -> tuple[np.ndarray, np.ndarray]:
        """The hover state at the reference's start, recorded, and the first VIO sample at
        ``t = 0``: ``(s, y)``."""
        rec, veh, vio, cam = self.rec, self.veh, self.vio, self.cam
        s = veh.hover_state(self.ref_p[0] + [*self.options.start_offset, 0.0], self.ref_v[0])
        if self.wind is not None:
            s[13:16] = self.wind[0]
        rec.S[0] = s
        self.ctrl.reset()
        vio.reset()
        rec.vio_t[0], rec.vio_x[0], rec.vio_q[0], rec.vio_w[0] = 0, s[0:6], s[6:10], s[10:13]
        if cam is None:
            rec.vio_e[0] = vio.sample(s[0:6], s[10:13], np.zeros(3))
        else:
            cam.check_view(s)
            cam.start(s)
            est, rec.vio_qe[0] = cam.estimate()
            rec.vio_e[0] = est - s[0:6]
        if self.fault is not None and self.fault_ns <= 0:
            rec.vio_e[0] += self.fault
        return s, rec.vio_x[0] + rec.vio_e[0]

    def flush(self, pending: int, m: int) -> np.ndarray:
        """Errors of the pending samples ``pending .. m - 1``; the newest estimate ``y``."""
        rec = self.rec
        e = self.vio.errors(rec.vio_x[pending:m], rec.vio_w[pending:m], rec.vio_a[pending:m])
        if self.fault is not None:
            e[rec.vio_t[pending:m] >= self.fault_ns] += self.fault
        rec.vio_e[pending:m] = e
        return rec.vio_x[m - 1] + rec.vio_e[m - 1]

    def sample(
        self, m: int, xv: np.ndarray, wv: np.ndarray, s: np.ndarray, s_next: np.ndarray, t_ns: int
    ) -> np.ndarray:
        """VIO sample ``m`` (at ``t_ns``, true state ``xv``, body rate ``wv``) made at once,
        not batched (camera loop, stepwise): its error recorded; ``y``."""
        rec = self.rec
        if self.cam is None:
            rec.vio_e[m] = self.vio.sample(xv, wv, (s_next[3:6] - s[3:6]) / self.h)
        else:
            est, rec.vio_qe[m] = self.cam.estimate()
            rec.vio_e[m] = est - xv
        if self.fault is not None and t_ns >= self.fault_ns:
            rec.vio_e[m] += self.fault
        return xv + rec.vio_e[m]

    def tick(
        self, i: int, k: int, s: np.ndarray, y_latest: np.ndarray, m: int
    ) -> tuple[float, np.ndarray] | None:
        """Controller tick ``k`` at physics step ``i`` (state ``s``, ``m`` VIO samples so far,
        the newest estimate ``y_latest``): its command recorded; the vehicle's thrust and
        attitude command, None when the controller's output is not finite."""
        rec, iface, t = self.rec, self.iface, i * self.h
        r = RefSample(p=self.ref_p[i], v=self.ref_v[i], a=self.ref_a[i], uff=self.ref_ff[k])
        if self.arrival is not None:  # the newest sample arrived by the tick
            tick_ns, dropped, arrival_ns = i * self.h_ns, self.dropped, self.arrival_ns
            while self.cursor + 1 < m and (
                dropped[self.cursor + 1] or arrival_ns[self.cursor + 1] <= tick_ns
            ):
                self.cursor += 1
                if not dropped[self.cursor]:
                    self.read = self.cursor
            y_latest = rec.vio_x[self.read] + rec.vio_e[self.read]
        y = s[0:6].copy() if self.truth_feedback else y_latest
        u = np.asarray(self.ctrl.command(t, y, s[6:10], r), dtype=float)
        if not np.all(np.isfinite(u)):
            return None
        if iface is None:
            thrust, cmd_q = self.veh.command(u)
        else:
            px4 = self.options.px4
            t_sp, q_d = iface.setpoint(u, r)
            thrust, cmd_q = self.veh.command_px4(t_sp, q_d, px4.hover_thrust)
            rec.c_sp[k, 0], rec.c_sp[k, 1:] = t_sp, q_d
        rec.c_t[k], rec.c_y[k], rec.c_r[k] = i * self.h_ns, y, r.state
        rec.c_u[k], rec.c_a[k], rec.c_ff[k] = u, r.a, r.uff
        return thrust, cmd_q

    def log(self, m: int, k: int, end: tuple[str, float, int] | None) -> FlightLog:
        """The flight's log: ``m`` VIO samples, ``k`` ticks, and the steps up to the last one
        (``end``: why the flight ended early, when and at which step; None: it did not)."""
        n = (self.n_steps if end is None else end[2]) + 1
        cam, vio, veh, m_ctrl = self.cam, self.vio, self.veh, self.m_ctrl
        return self.rec.log(
            self.ctrl, veh, self.t_ns[:n], np.hstack([self.ref_p[:n], self.ref_v[:n]]), n, m, k,
            crashed=end is not None, reason=end[0] if end else None,
            crash_t=end[1] if end else None, lipschitz=None if cam else vio.lipschitz,
            described=cam.describe() if cam else vio.describe(), camera=cam is not None,
            camera_frame=cam.snapshot.arrays() if cam is not None and cam.snapshot else None,
            px4=self.iface is not None, arrival=self.arrival,
            controller_mass=m_ctrl if m_ctrl != veh.mass else None,
        )  # fmt: skip


def _vio_arrivals(
    options: FlightOptions, seed: int, tick_ns: int, n_vio_max: int, vio_ns: int
) -> tuple[np.ndarray, np.ndarray] | None:
    """When each VIO sample reaches the controller (µs) and which never do, where samples are
    read by arrival (:attr:`Px4Options.timed`; None otherwise)."""
    px4 = options.px4
    if not px4.timed:
        return None
    if tick_ns % US:
        raise ConfigError(
            f"the control period ({tick_ns} ns) is not a whole number of "
            "microseconds, PX4's clock unit; choose vehicle.physics_hz so that it is"
        )
    rng = np.random.default_rng(np.random.SeedSequence([seed, _ESTIMATOR_STREAM]))
    return arrivals(
        np.arange(n_vio_max, dtype=np.int64) * vio_ns, px4.estimator_latency_s,
        px4.estimator_jitter_s, px4.estimator_drop, rng, keep_first=True,
    )  # fmt: skip


def _camera_loop(options: FlightOptions, seed: int, veh: Vehicle) -> CameraVio:
    """The camera loop of a flight (``vio.kind: camera``), in the active perception level."""
    # deferred: the camera loop loads OpenCV, which flights without a camera do not
    from qsls.pipeline.sim.camera.loop import CameraVio

    level = options.vio.level
    h_ns = round(NS / options.vehicle.physics_hz)
    return CameraVio(options.vio.camera, level.light, level.texture, seed, veh.g, h_ns)


def _crash_reason(
    s: np.ndarray, p_ref: np.ndarray, t: float, crash: CrashOptions, cos_tilt: float
) -> str | None:
    """Why the flight ends at state ``s`` (None: it goes on); plain floats, once per step."""
    v = s.tolist()
    if not all(map(math.isfinite, v)):
        return "the vehicle state became non-finite (divergence)"
    if v[2] < crash.floor_z:
        return f"ground contact at t = {t:.2f} s (height {v[2]:.3f} m)"
    bz = 1.0 - 2.0 * (v[6] * v[6] + v[7] * v[7])  # R[2, 2]: cosine of the tilt
    if bz < cos_tilt:
        return f"lost attitude at t = {t:.2f} s (tilt {np.degrees(np.arccos(np.clip(bz, -1, 1))):.0f} deg)"
    r = p_ref.tolist()
    dev = max(abs(v[0] - r[0]), abs(v[1] - r[1]), abs(v[2] - r[2]))
    if dev > crash.max_deviation:
        return f"diverged at t = {t:.2f} s ({dev:.2f} m from the reference)"
    return None
