"""The innovation monitor's calibration record (docs/monitor.md#the-calibrated-mode): the
``monitor`` field of a certificate's ``calibration``.

Each calibration flight's statistic is ``s_f = max_{k, w, c} |med_k,w,c| / threshold_w,c``: the
largest median window sum of innovations over the flight, its windows and its checked channels,
each divided by the sound threshold of its window and channel (``K per_tick_c + E_K,c``, as
widened). The calibrated thresholds are ``q`` times the sound ones, ``q`` the split-conformal
quantile of the ``n`` statistics (rank ``ceil((n + 1)(1 - a))``): a next flight exchangeable with
the calibration flights trips the window sums with probability at most ``a``
(:func:`qsls.pipeline.control.innovation.calibrated_innovation` applies it).

The record checks itself on load: the rank is the conformal rank of its statistics' count at
its rate and the quantile the statistic of that rank (a hand-edited quantile is refused).
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, field_validator, model_validator

from qsls.pipeline.control.conformal import conformal_rank

MonitorMode = Literal["sound", "calibrated"]
SOUND: MonitorMode = "sound"
CALIBRATED: MonitorMode = "calibrated"


def conformal_quantile(statistics: list[float], rate: float) -> tuple[int, float]:
    """``(rank, quantile)``: rank ``ceil((n + 1)(1 - rate))`` of the ``n`` statistics and the
    statistic of that rank (ascending; inf when the rank exceeds ``n``: too few flights)."""
    n = len(statistics)
    rank = conformal_rank(n, rate)
    return rank, (sorted(statistics)[rank - 1] if rank <= n else math.inf)


class MonitorCalibration(BaseModel):
    """``calibration.monitor``: which thresholds the innovation monitor flies and the quantile
    behind the calibrated ones (module docstring)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    mode: MonitorMode
    """``sound`` (the premise's bound: no trip on a flight whose premise held) or
    ``calibrated`` (``quantile`` times the sound thresholds, at most the sound ones)."""
    false_trip_rate: float
    """``a``: the stated probability that a next flight of the calibration's conditions trips
    the calibrated window sums (the quantile's rate; in sound mode the quantile is recorded
    for reference only)."""
    statistics: list[float]
    """Each calibration flight's ``s_f``, in the order of the record's ``scores``."""
    rank: int
    """``ceil((n + 1)(1 - a))`` (1-based, ascending)."""
    quantile: float
    """The statistic of rank ``rank`` (inf when ``rank > n``: the sound thresholds fly)."""

    @field_validator("false_trip_rate")
    @classmethod
    def _rate(cls, v: float) -> float:
        if not 0.0 < v < 1.0:
            raise ValueError(f"false_trip_rate {v} is not in (0, 1)")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> MonitorCalibration:
        if any(not (math.isfinite(s) and s >= 0) for s in self.statistics):
            raise ValueError("a monitor statistic is not a finite non-negative number")
        rank, q = conformal_quantile(self.statistics, self.false_trip_rate)
        if self.rank != rank:
            raise ValueError(
                f"monitor rank {self.rank}, the conformal rank of {len(self.statistics)} "
                f"statistics at rate {self.false_trip_rate:g} is {rank}"
            )
        if not (self.quantile == q or math.isclose(self.quantile, q, rel_tol=1e-12)):
            raise ValueError(f"monitor quantile {self.quantile}, its statistics' is {q}")
        return self

    @property
    def scale(self) -> float:
        """The calibrated thresholds' share of the sound ones: ``quantile`` widened by 1e-9
        relative (the statistic's own rounding), at most 1 (never above the sound bound); 1 in
        sound mode, and where the quantile is 0 or inf (no window filled; too few flights)."""
        q = self.quantile * (1.0 + 1e-9)
        if self.mode != CALIBRATED or not 0.0 < q < 1.0:
            return 1.0
        return q
