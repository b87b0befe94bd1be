"""The controllers a bound check reads: each folder's certificate and responses, verified
(:func:`~qsls.pipeline.control.artifacts.load_controller_dir`), with the numbers of the
certificate's guarantee (docs/guarantee.md#the-present-theorem)::

    gamma        = (eps_e + S a) / (1 - S ||Phi_xy||),  a = eps_w ||Phi_xx H|| + Delta
    gamma_strict = R0 / (1 - S ||Phi_xy||)

The norms are recomputed from the controller's taps, never read from the certificate; a
static-gain reference controller (PD) gets its closed loop's true norms
(:func:`~qsls.pipeline.control.nominal.static_gain_norms`), not its truncated taps'.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.control import guarantee
from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    Calibration,
    ControllerDir,
    load_controller_dir,
)
from qsls.pipeline.control.nominal import static_gain_responses
from qsls.pipeline.control.status import CERTIFIED, FAILED, RELAXED, SOLVER_INACCURATE
from qsls.pipeline.core.artifacts import sha256_file, sha256_path
from qsls.pipeline.core.errors import ConfigError, InputError
from qsls.pipeline.core.plant import GRAVITY, NX
from qsls.pipeline.evaluate.assumptions import CertifiedPremise
from qsls.pipeline.evaluate.conditions import outside_conditions, outside_family
from qsls.pipeline.premise import honest
from qsls.pipeline.premise.numbers import PremiseNumbers


@dataclass(frozen=True)
class ControllerBound:
    """What the bound check needs from one controller folder's certificate."""

    name: str
    folder: Path
    status: str
    robust: bool
    numbers: PremiseNumbers
    """The certificate's premise (:meth:`qsls.pipeline.control.artifacts.Certificate.numbers`)."""
    norm_phi_xx_h: float
    norm_phi_xy: float
    gamma_certificate: float
    model_sha256: str | None
    robustness_lhs: float | None = None
    certificate: dict[str, Any] = field(repr=False, default_factory=dict)
    phi_xy: np.ndarray | None = field(repr=False, compare=False, default=None)
    """The ``(T+1, nx, ny)`` taps of ``Phi_xy`` (the theorem's ``x_hat``); for a static gain
    (PD) the closed loop's taps to the horizon where its tail is negligible."""
    phi_xy_tail: float = 0.0
    """Bound on ``||Phi_xy||`` beyond ``phi_xy``'s taps (0 for a FIR controller)."""
    dt: float = math.nan
    """The controller's sample time."""
    norm_bias: float = 0.0
    """``G_b``, the peak gain from a constant bias (docs/guarantee.md#the-bias-term)."""
    beta: float = math.inf
    measure: str = "full"
    error_scale: tuple[float, ...] = (1.0,) * 6

    @property
    def generalized(self) -> bool:
        """The premise splits or weights the error (docs/guarantee.md): the premise here is on
        the dense part, and the guarantee is checked on the controller's own log."""
        return (
            self.measure != "full"
            or math.isfinite(self.beta)
            or any(w != 1.0 for w in self.error_scale)
        )

    def dense(self, e: np.ndarray) -> np.ndarray:
        """``|d_k|_e``: the part of the error the premise bounds by ``eps_e + S d_k``."""
        d, _ = honest.split_errors(e, self.beta, self.measure)
        return honest.weighted_norm(d, self.error_scale)

    @property
    def a_certificate(self) -> float:
        """The certificate's a-priori ``a = eps_w ||Phi_xx H|| + eps_b G_b + Delta``."""
        n = self.numbers
        return guarantee.a_value(n.eps_w, self.norm_phi_xx_h, n.delta, n.eps_b, self.norm_bias)

    @property
    def denominator(self) -> float:
        """``1 - S ||Phi_xy||``; the bound's formula is finite only when positive."""
        return guarantee.denominator(self.numbers.S, self.norm_phi_xy)

    @property
    def finite(self) -> bool:
        return self.denominator > 0

    @property
    def no_guarantee_reason(self) -> str | None:
        """Why the theorem does not apply to this controller (``None``: it does)."""
        if not self.finite:
            return f"S*||Phi_xy|| = {self.numbers.S * self.norm_phi_xy:.3g} >= 1"
        if self.status in (FAILED, SOLVER_INACCURATE):
            return f"certificate status '{self.status}'"
        if self.robustness_lhs is not None and self.robustness_lhs >= 1.0:
            return f"robustness condition not met (lhs {self.robustness_lhs:.3g} >= 1)"
        return None

    @property
    def has_guarantee(self) -> bool:
        """The theorem applies: finite bound, a verified controller, and the robustness
        condition met (lhs < 1, the certificate's ``robustness_lhs``); a nominal or PD
        controller usually misses the last."""
        return self.no_guarantee_reason is None

    @property
    def r0(self) -> float:
        """The paper's error bound ``R0`` (``eps`` when the certificate sets none)."""
        n = self.numbers
        return n.eps if n.R0 is None else n.R0

    @property
    def gamma_strict(self) -> float:
        """``R0 / (1 - S ||Phi_xy||)`` (inf when ``S ||Phi_xy|| >= 1``)."""
        return guarantee.gamma_strict_of(self.r0, self.numbers.S, self.norm_phi_xy)

    def gamma_at(self, distance: np.ndarray) -> np.ndarray:
        """``gamma_k = (eps_e + S (eps_w ||Phi_xx H|| + eps_b G_b + d_k)) / (1 - S ||Phi_xy||)``."""
        n = self.numbers
        d = np.asarray(distance, dtype=float)
        a = guarantee.a_value(n.eps_w, self.norm_phi_xx_h, d, n.eps_b, self.norm_bias)
        return np.asarray(guarantee.gamma_of(self.numbers.eps, self.numbers.S, self.norm_phi_xy, a))

    def premise_at(self, distance: np.ndarray) -> np.ndarray:
        """The S-slope premise ``eps_e + S d_k``: the error the assumption allows at ``x_k``."""
        return np.asarray(
            guarantee.premise_bound(
                self.numbers.eps, self.numbers.S, np.asarray(distance, dtype=float)
            )
        )


def certified_premise(folder: Path) -> Any:
    """What the certificate in ``folder`` promises, for the checks on its own flights
    (:class:`qsls.pipeline.evaluate.assumptions.CertifiedPremise`); None for a controller
    without a guarantee to check (a reference, a nominal or a failed one)."""
    return premise_of(load_controller_dir(folder))


def premise_of(d: ControllerDir) -> CertifiedPremise | None:
    """:func:`certified_premise` of a controller folder already read."""
    c = d.certificate
    if c.status not in (CERTIFIED, RELAXED) or not c.robust or c.rho_star is None:
        return None
    p = c.premise
    model = d.controller.model
    return CertifiedPremise(
        numbers=c.numbers(), a=c.a, rho_star=c.rho_star,
        beta=math.inf if p is None or p.beta is None else p.beta,
        measure=c.measure,
        error_scale=tuple(p.error_scale) if p is not None else (1.0,) * 6,
        phi_xy=physical(d.controller.taps.Phi_xy), A=model.A, B=model.B,
        H=model.H[:NX, :NX],
        u_hover=np.array([0.0, 0.0, model.mass * GRAVITY]),
        bias_dirs=model.bias_dirs[:NX],
    )  # fmt: skip


def physical(phi_xy: np.ndarray) -> np.ndarray:
    """``Phi_xy`` from the measured errors to the physical states: the attitude plant's extra
    states and error-free channels dropped (docs/model.md)."""
    return phi_xy[:, :NX, :NX]


def load_controller_bound(folder: Path) -> ControllerBound:
    """The bound's numbers from a verified controller folder (:func:`load_controller_dir`):
    the setting from its certificate, the norms ``||Phi_xy||`` and ``||Phi_xx H||`` recomputed
    from its responses."""
    d = load_controller_dir(folder)
    c, taps = d.certificate, d.controller.taps
    ctrl = d.controller
    # a reference controller is a closed loop, not a FIR: its true norms (long horizon plus a
    # geometric tail bound), never the truncated taps' (docs/synthesis.md#the-papers-controllers)
    norms = ctrl.norms()
    xy = norms["phi_xy"]
    norm_xy, norm_xx_h, tail = xy.value, norms["phi_xx_h"].value, xy.tail_bound
    phi_xy = taps.Phi_xy
    if ctrl.K is not None and ctrl.kind == "static_gain" and math.isfinite(norm_xy):
        phi_xy = static_gain_responses(ctrl.model, ctrl.K, xy.horizon).Phi_xy
    return ControllerBound(
        name=d.name,
        folder=d.folder,
        status=c.status,
        robust=c.robust,
        numbers=c.numbers(),
        norm_phi_xx_h=norm_xx_h,
        norm_phi_xy=norm_xy,
        gamma_certificate=c.gamma,
        model_sha256=c.error_model_sha256,
        robustness_lhs=c.robustness_lhs,
        certificate=c.model_dump(),
        phi_xy=physical(phi_xy),
        phi_xy_tail=tail,
        dt=float(ctrl.dt),
        norm_bias=float(c.G_b or 0.0),
        beta=math.inf if c.premise is None or c.premise.beta is None else c.premise.beta,
        measure=c.measure,
        error_scale=tuple(c.premise.error_scale) if c.premise is not None else (1.0,) * 6,
    )


def load_bounds(folders: Sequence[Path]) -> list[ControllerBound]:
    """Every folder's bound, names made unique (``<synth folder>-<controller>`` on a clash,
    e.g. two synth outputs that both hold ``l1_robust``)."""
    from collections import Counter
    from dataclasses import replace

    bounds = [load_controller_bound(f) for f in folders]
    counts = Counter(b.name for b in bounds)
    return [
        replace(b, name=f"{b.folder.parent.name}-{b.name}") if counts[b.name] > 1 else b
        for b in bounds
    ]


def check_model_hash(bound: ControllerBound, model_file: Path, *, force: bool) -> str | None:
    """Compare the controller's recorded error-model hash with ``model_file``'s.

    Returns a warning (hash differs and ``force``, or no hash recorded), ``None`` when they
    match; raises :class:`InputError` when they differ and not ``force``.
    """
    # "certified" only for a certified controller: the others were designed against it
    done = "certified" if bound.status == CERTIFIED else "designed"
    if bound.model_sha256 is None:
        return f"{bound.name}: certificate records no error-model hash; cannot check it was {done} against this model"
    ours = {sha256_file(model_file), sha256_path(model_file.parent)}
    if bound.model_sha256 in ours:
        return None
    msg = (
        f"{bound.name}: {done} against error model {bound.model_sha256[:12]}, "
        f"but --model is {sha256_file(model_file)[:12]}"
    )
    if not force:
        raise InputError(
            f"{bound.name}: pass the error model it was {done} with, or --force to check "
            f"anyway; {msg.removeprefix(bound.name + ': ')}"
        )
    return msg + " (checked anyway: --force)"


def expand_controllers(folders: Sequence[Path]) -> list[Path]:
    """Controller folders; a synth output folder stands for every controller inside it."""
    out: list[Path] = []
    for f in folders:
        f = Path(f)
        if not f.is_dir():
            raise InputError(f"{f}: no such controller folder")
        if (f / CERTIFICATE_FILE).is_file():
            out.append(f)
            continue
        inner = sorted(p for p in f.iterdir() if p.is_dir() and (p / CERTIFICATE_FILE).is_file())
        if not inner:
            raise InputError(
                f"{f}: no {CERTIFICATE_FILE} (and no controller folders inside); pass a "
                "controller folder written by 'qsls synth'"
            )
        out.extend(inner)
    return out


# --------------------------------------------------------------------------- per condition
def load_conditioned(
    by_condition: Mapping[str, Sequence[Path]] | None,
    names: Sequence[str],
    conditions: Sequence[str] | None = None,
) -> dict[tuple[str, str], ControllerBound]:
    """``{(condition, name): bound}``: the certificates calibrated per perception condition
    (a calibration's ``calibrate/<condition>/``) of the controllers ``names``, for the
    ``conditions`` flown (every one given when ``None``)."""
    wanted = set(names)
    return {
        (str(cond), b.name): b
        for cond, folders in (by_condition or {}).items()
        if conditions is None or cond in conditions
        for b in load_bounds([f for f in folders if f.name in wanted])
    }


def certificate_for(
    name: str,
    condition: str,
    bounds: Mapping[str, ControllerBound],
    by_condition: Mapping[tuple[str, str], ControllerBound] | None,
) -> ControllerBound | None:
    """The certificate a flight of perception ``condition`` is checked against for controller
    ``name``: the one calibrated for that condition (``calibrate/<condition>/<name>``) where
    there is one, else the controller's own (docs/calibration.md, "One certificate per
    condition")."""
    own = (by_condition or {}).get((condition, name))
    return own if own is not None else bounds.get(name)


def calibration_of(folder: Path) -> Calibration | None:
    """The calibration record of the certificate in ``folder`` (None: not calibrated)."""
    return load_controller_dir(folder).certificate.calibration


def refuse_evidence_seeds(folders: Sequence[Path], seeds: Sequence[int]) -> None:
    """A flight on a seed a certificate's calibration flew is that flight again (the same
    bytes), not fresh evidence: refused in one line (:class:`ConfigError`)."""
    for folder in folders:
        cal = calibration_of(folder)
        shared = sorted(set(seeds) & set(cal.evidence_seeds)) if cal is not None else []
        if shared:
            raise ConfigError(
                f"seeds {shared[:5]} were flown by {folder.name}'s calibration (calibration, "
                "range or validation flights): flown again they are those flights, not fresh "
                "evidence; choose other seeds"
            )


def outside_calibration(
    cal: Calibration | None,
    condition: str,
    flight_s: float,
    estimator: str = "",
    conditions: Mapping[str, Any] | None = None,
) -> str:
    """Why a flight of perception ``condition`` (``''``: not known, as for a recorded log)
    lasting ``flight_s``, its estimate from ``estimator`` (``camera``, ``emulator``; ``''``:
    not known), its other recorded ``conditions`` (vehicle, reference, VIO parameters:
    :func:`qsls.pipeline.evaluate.conditions.flight_conditions`; None: not known), lies
    outside the conditions a certificate was calibrated under (``cal``, its record; ``''``
    when inside, or when it has no calibration):
    :func:`qsls.pipeline.evaluate.conditions.outside_conditions` and
    :func:`qsls.pipeline.evaluate.conditions.outside_family`."""
    if cal is None:
        return ""
    calibrated = str(cal.conditions.get("perception", ""))
    why = outside_conditions(
        condition or calibrated, flight_s, calibrated, cal.duration_s,
        estimator, str(cal.conditions.get("estimator", "")),
    )  # fmt: skip
    family = outside_family(cal.conditions, conditions) if conditions else []
    return "; ".join([w for w in (why, *family) if w])
