"""Tuning the PD for tracking at its 10 Hz in regular perception (the paper: "Well-tuned PD
controller. This controller was tuned to track very well under ideal perception
conditions").

The procedure: for each pair ``(kp, kd)`` of a grid (the horizontal gains; the height's stay
as given), fly the PD at its control rate over the reference in regular perception with the
chosen estimator, on the tuning seeds, and score the pair by the mean over seeds of the
tracking RMS ``||p - p_ref||_2`` over the circle with the paper's 1 s smoothing
(:func:`qsls.pipeline.fly.paper.window_stats`); a crash scores ``inf``. The tuned gains
are the pair with the lowest score. Deterministic (seeded flights, a fixed grid, ties to the
first pair in grid order).

The tuning seeds are design flights: the gains are a number chosen after looking at data,
so the flights that judge the tuned PD (the fly stage's seeds) must be others.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from pydantic import BaseModel, ConfigDict

from qsls.pipeline.core.pools import run_tasks
from qsls.pipeline.core.units import NS
from qsls.pipeline.fly.paper import window_stats
from qsls.pipeline.sim.closedloop import FlightOptions, fly


class TunedPD(BaseModel):
    """The tuned gains, the score of every grid pair, and what was flown."""

    model_config = ConfigDict(frozen=True)

    kp: tuple[float, float, float]
    kd: tuple[float, float, float]
    score_m: float
    """Mean over the tuning seeds of the circle's smoothed tracking RMS (m)."""
    grid: tuple[tuple[float, float, float], ...]
    """``(kp, kd, score)`` per pair, in grid order (``inf``: a flight crashed)."""
    seeds: tuple[int, ...]
    estimator: str
    rate_hz: float


def _score(job: tuple[dict[str, Any], int]) -> float:
    """One tuning flight's circle tracking RMS (``inf`` if it crashed)."""
    import numpy as np

    data, seed = job
    opts = FlightOptions.model_validate({**data, "seed": seed})
    log = fly(opts)
    if log.crashed:
        return math.inf
    dp = np.linalg.norm(log.x[:, :3] - log.ref[:, :3], axis=1)
    rms, _ = window_stats(log.t_ns / NS, dp, float(opts.reference.start_s))
    return rms if math.isfinite(rms) else math.inf


def tune_pd(
    flight: dict[str, Any],
    kp_grid: Sequence[float],
    kd_grid: Sequence[float],
    seeds: Sequence[int],
    *,
    kp_z: float = 4.0,
    kd_z: float = 3.0,
    workers: int = 1,
) -> TunedPD:
    """The module docstring's procedure. ``flight``: the flight options (reference, vehicle,
    ``vio``; its perception is set to ``regular`` and its controller to the PD at
    ``controller.rate_hz``, default 10 Hz)."""
    ctrl = dict(flight.get("controller") or {})
    rate = float(ctrl.get("rate_hz") or 10.0)
    vio = {**(flight.get("vio") or {}), "perception": "regular"}
    pairs = [(float(kp), float(kd)) for kp in kp_grid for kd in kd_grid]
    jobs: list[tuple[dict[str, Any], int]] = []
    for kp, kd in pairs:
        pd = {"kp": (kp, kp, kp_z), "kd": (kd, kd, kd_z)}
        data = {**flight, "vio": vio, "controller": {"kind": "pd", "rate_hz": rate, "pd": pd}}
        jobs.extend((data, int(s)) for s in seeds)
    scores = run_tasks([(_score, j) for j in jobs], max(1, workers), lambda i: None)
    n = len(seeds)
    means = [sum(scores[i * n : (i + 1) * n]) / n for i in range(len(pairs))]
    best = min(range(len(pairs)), key=lambda i: means[i])
    kp, kd = pairs[best]
    vio_kind = str(vio.get("kind", "emulator"))
    return TunedPD(
        kp=(kp, kp, kp_z),
        kd=(kd, kd, kd_z),
        score_m=means[best],
        grid=tuple((p[0], p[1], m) for p, m in zip(pairs, means, strict=True)),
        seeds=tuple(int(s) for s in seeds),
        estimator=vio_kind,
        rate_hz=rate,
    )


__all__ = ["TunedPD", "tune_pd"]
