"""The options of ``qsls fit`` (and the ``fit:`` section of a config file), apart from the
stage: this module imports only pydantic and the core, so ``qsls run`` validates a run config
without loading pandas or scipy. :mod:`qsls.pipeline.errormodel.fit` re-exports them."""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import Field, field_validator

from qsls.pipeline.core.config import Options, Seed
from qsls.pipeline.core.plant import PAPER_MASS_KG, Plant
from qsls.pipeline.core.references import ReferenceOptions


class FitOptions(Options):
    """``qsls fit``: how the error model is estimated from the training flights."""

    radius: float = Field(0.5, gt=0)
    """S-slope radius ``r``: pairs with ``||W (x_i - x_j)|| < r`` (m and m/s, infinity norm)."""
    percentiles: list[float] = Field(default_factory=lambda: [50.0, 90.0, 95.0, 99.0])
    """Percentiles reported for ``||e||``, pair slopes and per-sample largest slopes."""
    min_separation: float | Literal["auto"] = "auto"
    """Pairs closer than this are left out: a number, or ``auto`` (``min_separation_factor`` x
    the noise floor of ``e`` estimated from the data); below the measurement noise, slopes are
    noise / distance and blow up. 0 keeps every pair at a positive distance."""
    min_separation_factor: float = Field(3.0, gt=0)
    """``auto`` minimum separation = this x the estimated noise floor."""
    state_scale: tuple[float, float, float, float, float, float] = (1.0,) * 6
    """Weights ``W`` of ``px py pz vx vy vz`` in the state distance (1 m/s counts as 1 m)."""
    exclude_outliers: bool = False
    """Leave out samples whose robust z-score of ``e`` (median/MAD) exceeds ``outlier_z`` on some
    axis; the count is reported."""
    outlier_z: float = Field(3.5, gt=0)
    """Robust z-score ``|e - median| / (1.4826 MAD)`` above which a sample is an outlier."""
    skip_start: float = Field(0.0, ge=0)
    """Seconds left out at the start of every flight (estimator start-up)."""
    environments: list[str] | None = None
    """One name per flight, in the flights' order: states of two environments (another room,
    another motion-capture frame) are never compared, so pairs, leave-one-flight-out distances
    and the tested range stay within one (default: all flights share one)."""
    reference: ReferenceOptions | str | None = None
    """For ``delta`` (the reference's largest distance to the nearest training state): a
    reference (``circle:radius=1,height=1,period=5``: the simulator's reference options, kind
    circle, hover or figure8; radius, height, period, laps, ramp_s, center=X;Y; or their
    mapping) or a flight folder whose truth states are the reference; default: none, delta 0."""
    reference_dt: float = Field(0.01, gt=0)
    """Sampling step of a parametric reference (s)."""
    reference_lead_in: bool = False
    """Include a parametric reference's take-off and approach (before its pattern) in delta."""
    r0: float | str = "max"
    """``R0``: ``max`` (= eps_e), ``pNN`` (a percentile of ``||e||``) or a number."""
    bootstrap: int = Field(0, ge=0, le=100_000)
    """Bootstrap replicates for confidence intervals (moving blocks within each flight; costs
    about N times the pair pass); 0: none."""
    bootstrap_block: int = Field(10, ge=1)
    """Block length (samples) of the moving-block bootstrap within each flight."""
    bootstrap_level: float = Field(0.95, gt=0, lt=1)
    """Confidence level of the bootstrap intervals."""
    seed: Seed = 0
    """Seed of the bootstrap."""
    top_pairs: int = Field(20, ge=1, le=1000)
    """Number of worst pairs reported."""
    figures: bool = True
    """Write the PNG figures."""
    jobs: int = Field(1, ge=1, le=64)
    """Threads for the pair pass (the result does not depend on it)."""
    inputs: list[str] | None = None
    """Logged inputs, one control log per flight in the flights' order (parquet with
    ``stamp_ns``, ``u_pitch``, ``u_roll``, ``u_thrust`` on the VIO clock, as ``qsls simulate``
    writes ``control.parquet``): the realized disturbance ``w`` is measured with them; without
    them it is the input-free residual, a lower bound (docs/guarantee.md)."""
    mass: float = Field(PAPER_MASS_KG, gt=0)
    """Vehicle mass (kg) of the model the disturbance is measured through (hover thrust, B)."""
    plant: Plant = "hover"
    """The model the disturbance is measured through (docs/model.md): ``hover``, the paper's
    6 states, or ``attitude``, with the attitude loop and the rotor lag as states. Synthesis
    must use the same plant (synth refuses another)."""

    @field_validator("percentiles")
    @classmethod
    def _pcts(cls, v: list[float]) -> list[float]:
        if not v:
            raise ValueError("give at least one percentile")
        bad = [q for q in v if not (0 <= q <= 100)]
        if bad:
            raise ValueError(f"percentiles must be in [0, 100], got {bad}")
        return sorted({float(q) for q in v})

    @field_validator("state_scale", mode="before")
    @classmethod
    def _scale(cls, v: Any) -> Any:
        if isinstance(v, list | tuple):
            if len(v) != 6:
                raise ValueError(f"give 6 weights (px,py,pz,vx,vy,vz), got {len(v)}")
            if any(not isinstance(w, int | float) or not w > 0 for w in v):
                raise ValueError(f"weights must be positive numbers, got {list(v)}")
        return v

    @field_validator("min_separation")
    @classmethod
    def _minsep(cls, v: float | str) -> float | str:
        if isinstance(v, float | int) and (v < 0 or not math.isfinite(v)):
            raise ValueError(f"must be >= 0 or 'auto', got {v}")
        return v
