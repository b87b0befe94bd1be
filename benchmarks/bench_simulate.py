"""Benchmark: a 60 s flight simulated and written, against RotorPy's stock loop.

Run: ``python benchmarks/bench_simulate.py [--duration 60] [--smoke]`` (``--smoke``,
``smokemode.py``: a 3 s flight)

Cases (same vehicle, same circle, SE3 at 100 Hz):

1. ``qsls simulate`` (library call): RK4 physics at 200 Hz, VIO emulator at 100 Hz in the
   loop, motion capture at 120 Hz, everything written (ROS1 bag, truth.json, parquet files).
2. the same at 100 Hz physics (RotorPy's step size).
3. qsls's loop on true-state feedback at 100 Hz (no VIO, nothing written): the like-for-like
   comparison with 4.
4. RotorPy's stock loop: ``SE3Control.update`` + ``Multirotor.step`` (``solve_ivp`` every
   step) at 100 Hz on true state, as RotorPy's own ``simulate`` does.

Also reported: the largest position difference between 3 and 4 over the flight (the
fixed-step integrator against ``solve_ivp`` on the same flight).
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from smokemode import add_flag, require


def _timed(fn):  # type: ignore[no-untyped-def]
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def stock_rotorpy(duration: float, hz: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    """RotorPy's own loop: SE3Control.update then Multirotor.step (solve_ivp) each step."""
    from rotorpy.controllers.quadrotor_control import SE3Control
    from rotorpy.vehicles.multirotor import Multirotor

    from qsls.pipeline.core.references import Reference
    from qsls.pipeline.sim.vehicle import Vehicle, quad_params

    params = quad_params()
    veh = Multirotor(params, control_abstraction="cmd_ctatt", aero=True)
    se3 = SE3Control(params)
    ref = Reference()
    dt = 1.0 / hz
    n = round(duration * hz)
    t = np.arange(n + 1) * dt
    rp, rv, ra = ref.arrays(t)
    s0 = Vehicle().hover_state(rp[0], rv[0])
    state = {k: np.array(v, dtype=float) for k, v in Multirotor._unpack_state(s0).items()}
    xs = np.empty((n + 1, 3))
    xs[0] = state["x"]
    z3 = np.zeros(3)
    for i in range(n):
        flat = {"x": rp[i], "x_dot": rv[i], "x_ddot": ra[i], "x_dddot": z3, "x_ddddot": z3,
                "yaw": 0.0, "yaw_dot": 0.0}  # fmt: skip
        ctrl = se3.update(t[i], state, flat)
        # cmd_ctatt uses thrust + attitude; SE3's attitude read back with yaw 0 like qsls
        from qsls.pipeline.sim.vehicle import ctatt_to_paper, paper_to_ctatt

        thrust, q = paper_to_ctatt(ctatt_to_paper(ctrl["cmd_thrust"], ctrl["cmd_q"]))
        state = veh.step(state, {"cmd_thrust": thrust, "cmd_q": q}, dt)
        xs[i + 1] = state["x"]
    return t, xs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0)
    add_flag(ap)
    args = ap.parse_args()
    d = 3.0 if args.smoke else args.duration

    from qsls.pipeline.sim.closedloop import FlightOptions, fly
    from qsls.pipeline.sim.simulate import SimOptions, simulate

    fly(FlightOptions(duration=0.5))  # imports and caches out of the timings
    tmp = Path(tempfile.mkdtemp(prefix="bench_sim_"))
    rows = []
    try:
        for hz in (200.0, 100.0):
            opts = SimOptions.model_validate({"duration": d, "vehicle": {"physics_hz": hz}})
            res, wall, cpu = _timed(lambda o=opts, h=hz: simulate(o, tmp / f"sim{int(h)}"))
            size = sum(f.stat().st_size for f in (tmp / f"sim{int(hz)}").rglob("*") if f.is_file())
            msgs = res.truth["vio_messages"] + res.truth["mocap_messages"]
            rows.append((f"qsls simulate, RK4 {hz:.0f} Hz, VIO+mocap, ros1 written", wall, cpu,
                         f"{msgs} msgs, {size / 1e6:.1f} MB"))  # fmt: skip
        opts = FlightOptions.model_validate(
            {"duration": d, "vehicle": {"physics_hz": 100}, "controller": {"feedback": "truth"}}
        )
        ours, wall, cpu = _timed(lambda: fly(opts))
        rows.append(("qsls loop, RK4 100 Hz, true state, not written", wall, cpu, ""))
        (_t, xs), wall, cpu = _timed(lambda: stock_rotorpy(d))
        rows.append(
            ("RotorPy stock: SE3Control + Multirotor.step (solve_ivp), 100 Hz", wall, cpu, "")
        )
        diff = float(np.abs(ours.x[:, :3] - xs[: len(ours.x)]).max())
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    print(f"\n{d:g} s of flight, circle r = 1 m at 0.2 Hz, SE3 at 100 Hz\n")
    print(f"{'case':<66} {'wall s':>8} {'cpu s':>8}  notes")
    print("-" * 100)
    for name, wall, cpu, note in rows:
        print(f"{name:<66} {wall:8.2f} {cpu:8.2f}  {note}")
    stock = rows[-1]
    print("-" * 100)
    print(f"speed-up of the full qsls simulate (200 Hz) over the stock loop: "
          f"{stock[1] / rows[0][1]:.1f}x wall, {stock[2] / rows[0][2]:.1f}x cpu")  # fmt: skip
    print(f"like for like (loop only, 100 Hz): {stock[1] / rows[2][1]:.1f}x wall, "
          f"{stock[2] / rows[2][2]:.1f}x cpu")  # fmt: skip
    print(f"max |p_qsls - p_rotorpy| over the same flight: {diff * 1e3:.4f} mm")
    require(bool(np.isfinite(diff)), "both loops fly the whole flight")
    print(
        f"target: 60 s simulated and written in <= 10 s -> {'met' if rows[0][1] <= 10 * d / 60 else 'MISSED'}"
    )


if __name__ == "__main__":
    main()
