"""Whether a recorded flight was flown by a candidate controller (docs/vehicle.md#proof).

A recorded flight counts as the candidate's own only if the candidate, fed what the vehicle's
controller read, sends what the vehicle's controller sent. Replayed on the flight's tick log
(:mod:`qsls.pipeline.ingest.ticks`, each ``y_k`` the estimate that had arrived at tick ``k``,
so the estimator's latency is the log's own):

    u'_k = u_hover + uff_k + K(gate(y_k - r_k))        (the candidate's step, reset at tick 0)

then through the export's attitude map with its limits (the command a vehicle can be sent)
and back to the paper's input (:mod:`qsls.pipeline.core.attitude`), and compared with the
recorded ``u_k``. The flight is refused at the first tick where a channel differs by more than
:data:`TOLERANCE` (rad for pitch and roll; for thrust, that fraction of ``m g``).

The tolerance covers what a log does to exact numbers, nothing a controller does: a ULog keeps
float32 (relative 2^-24 = 6e-8), so estimates of a few metres carry 1e-6 m of rounding, which
the controller's gain (an induced norm of a few tens) turns into 1e-5 of input; the command's
own rounding is 1e-7. A different controller, or the same taps behind another gate at a tick
where the gate binds, differs by the gain times that difference (0.01 of input and more). An
identity stamped in the log (``qsls_controller_sha256``, ``qsls_gate``) is compared first,
where present.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.control.artifacts import load_controller_dir, load_runtime
from qsls.pipeline.control.gate import gated_deviation
from qsls.pipeline.core.attitude import force_from_attitude, input_from_force
from qsls.pipeline.core.plant import GRAVITY
from qsls.pipeline.core.ticks import INPUT, TickLog
from qsls.pipeline.export.attitude import AttitudeLimits, thrust_attitude

TOLERANCE = 1e-4
"""Largest difference between a replayed and a recorded command (module docstring)."""


@dataclass(frozen=True)
class Provenance:
    """The verdict: ``flown`` or why not (``reason``, the first differing ``tick``)."""

    controller: str
    flown: bool
    reason: str = ""
    tick: int | None = None
    max_difference: float = 0.0


def replayed_inputs(
    log: TickLog, folder: Path, mass: float, limits: AttitudeLimits = AttitudeLimits()
) -> np.ndarray:
    """``u'_k`` (k, 3): the candidate's commands on the log's estimates, limited as the
    vehicle is sent them, in the paper's input (module docstring)."""
    cert = load_controller_dir(folder).certificate
    runtime: Any = load_runtime(folder)
    runtime.reset()
    g = GRAVITY
    dev = gated_deviation(log.y - log.ref, cert.gate)
    out = np.empty((len(log.t), 3))
    for k in range(len(log.t)):
        out[k] = np.asarray(runtime.step(dev[k]), dtype=float).reshape(3)
    acc = np.column_stack([-log.uff[:, 0] * g, log.uff[:, 1] * g, log.uff[:, 2] / mass])
    thrust, q = thrust_attitude(out, acc, mass, limits)
    return input_from_force(force_from_attitude(q, thrust), mass)


def check_identity(stamps: dict[str, Any], folder: Path) -> str:
    """Why the identity stamped in the log is not ``folder``'s ('' when it is, or when the
    log stamps none)."""
    cert = load_controller_dir(folder).certificate
    sha = stamps.get("qsls_controller_sha256")
    if sha and sha != cert.controller_sha256:
        return (
            f"the log names controller {stamps.get('qsls_controller', '?')} (sha256 "
            f"{str(sha)[:12]}..), not {folder.name} ({cert.controller_sha256[:12]}..)"
        )
    gate = stamps.get("qsls_gate")
    if gate not in (None, ""):
        logged = None if gate == "none" else float(gate)
        same = (logged is None and cert.gate is None) or (
            logged is not None and cert.gate is not None
            and math.isclose(logged, cert.gate, rel_tol=1e-6)
        )  # fmt: skip
        if not same:
            return (
                f"the log's controller reads through gate {gate}, {folder.name} through {cert.gate}"
            )
    return ""


def flown_by(
    log: TickLog, folder: Path, mass: float, stamps: dict[str, Any] | None = None
) -> Provenance:
    """Whether the candidate in ``folder`` flew the flight of ``log`` (module docstring)."""
    name = Path(folder).name
    if why := check_identity(stamps or {}, Path(folder)):
        return Provenance(name, False, why)
    replay = replayed_inputs(log, Path(folder), mass)
    scale = np.array([1.0, 1.0, mass * GRAVITY])
    diff = np.abs(replay - log.u) / scale
    worst = float(np.nanmax(diff)) if diff.size else 0.0
    bad = ~(diff <= TOLERANCE)
    if not bad.any():
        return Provenance(name, True, max_difference=worst)
    k, j = (int(v[0]) for v in np.nonzero(bad))
    unit = "rad" if j < 2 else "N"
    return Provenance(
        name, False,
        f"tick {k} (t = {log.t[k]:.3f} s): {INPUT[j]} {log.u[k, j]:.6g} {unit} recorded, "
        f"{replay[k, j]:.6g} {unit} replayed through {name} (tolerance {TOLERANCE:g}"
        + (" x m g)" if j == 2 else " rad)"),
        k, worst,
    )  # fmt: skip
