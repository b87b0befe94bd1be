"""Whether a recorded flight was flown by a candidate controller (docs/vehicle.md#proof).

A recorded flight counts as the candidate's own only if the candidate, fed what the vehicle's
controller read, sends what the vehicle's controller sent. Replayed on the flight's tick log
(:mod:`qsls.pipeline.ingest.ticks`, each ``y_k`` the estimate that had arrived at tick ``k``,
so the estimator's latency is the log's own):

    u'_k = u_hover + uff_k + K(gate(y_k - r_k))        (the candidate's step, reset at tick 0)

then through the export's attitude map with its limits (the command a vehicle can be sent)
and back to the paper's input (:mod:`qsls.pipeline.core.attitude`), and compared with the
recorded ``u_k``. The flight is refused at the first tick where a channel differs by more than
its tolerance (rad for pitch and roll; for thrust, a fraction of ``m g``).

The tolerance is what a log's rounding can do, derived per flight, nothing a controller does.
A ULog keeps float32 (unit roundoff ``eps = 2^-24``): each ``y_i`` and ``r_i`` carries at most
``eps (|y_i| + |r_i|)`` of rounding, which reaches input ``j`` through at most
``G_ji = sum_t |Phi_uy(t)_ji|`` (the taps' gain from channel ``i``), and the command itself
(the quaternion, the normalized thrust and the hover thrust) is rounded once more::

    tol_j = 4 eps (sum_i G_ji max_k(|y_ik| + |r_ik|) + max_k |u_jk| / s_j + 1)

(``s_j`` = 1 rad for pitch and roll, ``m g`` for thrust; the 4 covers the few roundings of
each conversion). Latency needs none: ``y_k`` is the estimate that had arrived, by the log's
own stamps. An identity stamped in the log (``qsls_controller_sha256``, ``qsls_gate``) is
compared first, where present.
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

EPS32 = 2.0**-24
"""float32's unit roundoff: a log's numbers."""
TOLERANCE = 1e-4
"""The largest tolerance any flight gets: beyond it no rounding explains a difference."""


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


def tolerances(log: TickLog, folder: Path, scale: np.ndarray) -> np.ndarray:
    """``tol_j`` (3,) of the module docstring: what float32 rounding of the log can change in
    each replayed input, capped at :data:`TOLERANCE`."""
    taps = load_controller_dir(folder).controller.taps
    gain = np.abs(taps.Phi_uy).sum(axis=0)[:, : log.y.shape[1]]  # (nu, 6)
    size = (np.abs(log.y).max(axis=0) + np.abs(log.ref).max(axis=0)) if len(log.t) else 0.0
    u = np.abs(log.u).max(axis=0) / scale if len(log.t) else np.zeros(3)
    tol = 4 * EPS32 * (gain @ size + u + 1.0)
    return np.minimum(tol, TOLERANCE)


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
    tol = tolerances(log, Path(folder), scale)
    bad = ~(diff <= tol)
    if not bad.any():
        return Provenance(name, True, max_difference=worst)
    k, j = (int(v[0]) for v in np.nonzero(bad))
    unit = "rad" if j < 2 else "N"
    return Provenance(
        name, False,
        f"tick {k} (t = {log.t[k]:.3f} s): {INPUT[j]} {log.u[k, j]:.6g} {unit} recorded, "
        f"{replay[k, j]:.6g} {unit} replayed through {name} (tolerance {tol[j]:.2g}"
        + (" x m g, the log's rounding)" if j == 2 else " rad, the log's rounding)"),
        k, worst,
    )  # fmt: skip
