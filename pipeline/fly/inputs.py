"""The flown commands against what PD would command from the same estimate (the paper's
input figure), and the motion that drives the emulator's blur.

``u = hover + u_ff + u_fb`` for PD and the synthesized controllers
(:class:`qsls.pipeline.sim.controllers.LinearController`); PD on another controller's
estimate ``y`` commands ``u_PD = hover + u_ff + K (y - r)``. Arrays in, numbers out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from qsls.pipeline.control.pdgain import pd_gain
from qsls.pipeline.core.plant import GRAVITY, PAPER_DT_S
from qsls.pipeline.core.references import Reference
from qsls.pipeline.sim.controllers import LinearController, PDController, make_controller
from qsls.pipeline.sim.simulate import SimOptions
from qsls.pipeline.sim.vehicle import Vehicle
from qsls.pipeline.sim.vio import VioEmulator


def pd_on_same_estimate(
    opts: SimOptions,
    mass: float,
    t: np.ndarray,
    y: np.ndarray,
    ref: np.ndarray,
    K: ArrayLike | None = None,
) -> np.ndarray:
    """``u_PD = hover + u_ff + K (y - r)`` (k, 3): what the PD controller would command from
    the estimate another controller saw (the paper's input figure). ``K``: the flown PD's
    gain (from the synth folder's ``pd``); default: the simulator's PD gains."""
    if len(t) == 0:
        return np.zeros((0, 3))
    gain = pd_gain(opts.controller.pd, mass) if K is None else np.asarray(K, dtype=float)
    return command_offset(opts, mass, t) + (y - ref) @ gain.T


def command_offset(opts: SimOptions, mass: float, t: np.ndarray) -> np.ndarray:
    """``hover + u_ff`` (k, 3): the part of PD's command that does not depend on the estimate,
    its feedforward the hover plant's (:meth:`qsls.pipeline.core.references.Reference.
    feedforward`; a synthesized controller's differs by its plant's lead terms)."""
    if len(t) == 0:
        return np.zeros((0, 3))
    dt = float(t[1] - t[0]) if len(t) > 1 else PAPER_DT_S
    ff = Reference(opts.reference).feedforward(t, dt, mass, "hover")  # as PD flies it
    return np.array([0.0, 0.0, mass * GRAVITY]) + ff


def input_comparison(u: np.ndarray, u_pd: np.ndarray, u_off: np.ndarray) -> dict[str, float]:
    """Attitude commands (pitch, roll) against PD's from the same estimate: RMS step change
    of each (roughness, rad per tick) and their ratio ``smoothness_vs_pd``; RMS of each
    feedback command ``u - u_off`` (``u_off = hover + u_ff``: the reaction to the estimate,
    rad) and their ratio ``reaction_vs_pd`` (< 1: softer than PD, the paper's input
    figure); and the RMS difference (rad)."""
    if len(u) < 2:
        keys = ("attitude_smoothness", "pd_attitude_smoothness", "smoothness_vs_pd",
                "reaction_rms", "pd_reaction_rms", "reaction_vs_pd", "attitude_diff_from_pd_rms")  # fmt: skip
        return dict.fromkeys(keys, math.nan)

    def rms(a: np.ndarray) -> float:
        return float(np.sqrt(np.mean(a**2)))

    a, b = rms(np.diff(u[:, :2], axis=0)), rms(np.diff(u_pd[:, :2], axis=0))
    ra, rb = rms(u[:, :2] - u_off[:, :2]), rms(u_pd[:, :2] - u_off[:, :2])
    return {
        "attitude_smoothness": a,
        "pd_attitude_smoothness": b,
        "smoothness_vs_pd": a / b if b > 0 else math.nan,
        "reaction_rms": ra,
        "pd_reaction_rms": rb,
        "reaction_vs_pd": ra / rb if rb > 0 else math.nan,
        "attitude_diff_from_pd_rms": rms(u[:, :2] - u_pd[:, :2]),
    }


def error_reaction(
    opts: SimOptions, mass: float, e: np.ndarray, K: ArrayLike | None = None
) -> dict[str, float]:
    """The controller's reaction to the estimation error alone against PD's: by linearity
    the feedback ``K (y - r) = K (x - r) + K e``, so ``u_e = K e`` (the flown controller's
    filter run from rest on the error sequence ``e`` (k, 6) at its ticks) and ``K_PD e``;
    ``error_reaction_vs_pd = RMS(u_e,att) / RMS(K_PD e)_att`` (< 1: it reacts less to
    estimation errors than PD). ``nan`` for a controller that is not a linear filter (SE3)."""
    nan = {"error_reaction_vs_pd": math.nan}
    if len(e) < 2 or opts.controller.kind == "se3":
        return nan
    ctrl = make_controller(opts.controller, mass)
    if isinstance(ctrl, PDController):
        u_e = e @ np.asarray(ctrl.K, dtype=float).T
    elif isinstance(ctrl, LinearController):
        ctrl.runtime.reset()
        u_e = np.array([np.asarray(ctrl.runtime.step(ek), dtype=float).reshape(3) for ek in e])
    else:
        return nan
    gain = pd_gain(opts.controller.pd, mass) if K is None else np.asarray(K, dtype=float)
    b = float(np.sqrt(np.mean((e @ gain.T)[:, :2] ** 2)))
    a = float(np.sqrt(np.mean(u_e[:, :2] ** 2)))
    return {"error_reaction_vs_pd": a / b if b > 0 else math.nan}


def motion_metrics(
    opts: SimOptions,
    seed: int,
    x: np.ndarray,
    w: np.ndarray,
    described: Mapping[str, Any] | None = None,
) -> dict[str, float]:
    """At the VIO samples: RMS of the body rate ``||omega||_2`` (rad/s), and the mean image
    blur (px) and features per frame of the estimator that flew. For the camera loop
    (``described``, its ``truth.json`` record, names the ``msckf``) the blur is the camera's
    own: its renderer's ``b`` over its own auto exposure ``t = min(t0 / L, t_max)``, averaged
    over the frames (docs/camera.md), with the features it tracked per frame. Otherwise the
    emulator's ``b_k`` with this condition's exposure (whether or not its blur part is
    switched on), and no features (``nan``)."""
    if len(x) == 0:
        return {"angular_rate_rms": math.nan, "blur_px_mean": math.nan,
                "features_per_frame": math.nan}  # fmt: skip
    rate = float(np.sqrt(np.mean(np.sum(w * w, axis=1))))
    if described is not None and described.get("estimator") == "msckf":
        return {
            "angular_rate_rms": rate,
            "blur_px_mean": float(described.get("blur_px_mean", math.nan)),
            "features_per_frame": float(described.get("features_per_frame", math.nan)),
        }
    blur = VioEmulator(opts.vio, seed).blur(x, w)
    return {
        "angular_rate_rms": rate,
        "blur_px_mean": float(np.mean(blur)),
        "features_per_frame": math.nan,
    }


class PdHeightController:
    """A synthesized controller's pitch and roll with the PD's thrust (paper, Controllers:
    "the z control of the PD controller was used instead")."""

    def __init__(self, inner: Any, pd: Any) -> None:
        self.inner, self.pd = inner, pd
        self.name = f"{inner.name}+pd_z"
        self.dt = inner.dt

    @classmethod
    def build(cls, opts: SimOptions, K: Any = None) -> PdHeightController:
        mass = Vehicle(opts.vehicle).mass
        inner = make_controller(opts.controller, mass)
        pd = PDController(opts.controller.pd, mass, inner.dt)
        if K is not None:
            pd.K = np.asarray(K, dtype=float)
        return cls(inner, pd)

    def reset(self) -> None:
        self.inner.reset()
        self.pd.reset()

    def command(self, t: float, y: np.ndarray, q: np.ndarray, ref: Any) -> np.ndarray:
        u = np.array(self.inner.command(t, y, q, ref), dtype=float)
        u[2] = self.pd.command(t, y, q, ref)[2]
        return u


__all__ = [
    "PdHeightController",
    "command_offset",
    "error_reaction",
    "input_comparison",
    "motion_metrics",
    "pd_on_same_estimate",
]
