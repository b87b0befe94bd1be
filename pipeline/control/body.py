"""What :func:`qsls.pipeline.control.certify.certify` finds on a controller's taps
(:class:`CertificateBody`), in a module of its own: the certificate file's model
(:mod:`qsls.pipeline.control.artifacts`) extends it and recomputes it with ``certify`` on every
load (docs/verify.md), so neither of those two modules may import the other's importer."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, field_validator

from qsls.pipeline.control.status import Status


class CertificateBody(BaseModel):
    """What :func:`qsls.pipeline.control.certify.certify` finds on a controller's taps: its
    status, the norms of its responses, the guarantee's numbers (docs/guarantee.md) and the
    checks, each recomputed from the taps. A :class:`Certificate` is this body with the setting
    it was checked against (:meth:`Certificate.of`)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    status: Status
    status_reason: str | None = None
    """Why the status is not ``certified`` (None when it is, or for a reference or nominal
    controller, whose status says it all)."""
    norm_phi_xx_h: float
    norm_phi_xy: float
    norm_phi_ux: float
    norm_phi_uy: float
    robustness_lhs: float
    margin: float
    s_times_norm_phi_xy: float
    a: float
    gamma: float
    """The bound on the dense error, ``eps + S rho*`` (Dean et al.'s gamma in the special case)."""
    gamma_strict: float
    rho_star: float | None = None
    """``dist(x_k) <= rho*`` for every k: the region the guarantee keeps the vehicle in."""
    norm_N: float | None = None
    norm_N_w: float | None = None
    G_m: float | None = None
    G_b: float | None = None
    """The peak gain from a constant acceleration bias (docs/guarantee.md#the-bias-term)."""
    rho_v: float | None = None
    """Certified bound on the velocity deviation from the reference (``<= V`` with a gate)."""
    achievability_residual: float
    truncation_residual: float | None = None
    """A reference controller's: its taps are a truncation, so the residual is the tail's."""
    realization_error: float | None = None
    perturbation_peak: float | None = None
    perturbation_final: float | None = None
    checks: dict[str, dict[str, Any]] | None = None
    """``name -> {value, limit, passed}`` (none for a reference controller)."""

    @field_validator("checks")
    @classmethod
    def _strict_checks(cls, v: dict[str, dict[str, Any]] | None) -> Any:
        """Each check a mapping whose ``passed`` is a YAML boolean: the string ``"false"`` is
        truthy in Python, so a loose type would read a failed check as passed."""
        for name, entry in (v or {}).items():
            if not isinstance(entry, dict):
                raise ValueError(f"check {name} is not a mapping")
            if not isinstance(entry.get("passed"), bool):
                raise ValueError(
                    f"check {name}: passed is {entry.get('passed')!r}, not true or false"
                )
        return v
