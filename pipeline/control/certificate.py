"""``certificate.yaml`` (:class:`Certificate`): the setting, norms, guarantee and checks of one
controller, and the sha256 of the ``controller.npz`` it certifies; and its load-time
verification (docs/verify.md).

Every reader recomputes a certificate's numbers: :meth:`Certificate.load` and
:func:`verified_controller` (which :func:`qsls.pipeline.control.artifacts.load_controller_dir`
runs) call :func:`qsls.pipeline.control.certify.certify` on the stored taps under the stored
(for a calibrated certificate: inflated) premise and refuse, in one line, a certificate whose
norms, guarantee numbers or checks differ from what its taps give
(:func:`recomputation_problems`), or whose calibration record disagrees with itself
(:func:`record_consistency`).
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path
from typing import Any, Literal

from pydantic import field_validator, model_serializer

from qsls.pipeline.control.body import CertificateBody
from qsls.pipeline.control.calibration_record import Calibration, record_problems
from qsls.pipeline.control.certify import (
    ACHIEVABILITY_TOL,
    PERTURBATION_TOL,
    REALIZATION_TOL,
    certify,
)
from qsls.pipeline.control.conformal import calibrated_quantile, calibration_rank
from qsls.pipeline.control.controller import (
    CONTROLLER_FILE,
    Controller,
    check_controller_name,
    in_folder,
    name_problem,
)
from qsls.pipeline.control.nominal import ClosedLoopNorm
from qsls.pipeline.control.problem import premise_shape
from qsls.pipeline.control.status import CERTIFIED, EXTRAPOLATED, REFERENCE
from qsls.pipeline.core.artifacts import atomic_write_bytes, dump_yaml, load_yaml
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.premise.numbers import PremiseNumbers
from qsls.pipeline.premise.record import Premise

CERTIFICATE_FILE = "certificate.yaml"


class Certificate(CertificateBody):
    """``certificate.yaml``: what was certified (the :class:`CertificateBody`), against which
    setting, and the checks.

    The guarantee (docs/guarantee.md, :mod:`qsls.pipeline.control.guarantee`): when
    ``robustness_lhs = (S + eps/r) N + (a + eps_o G_m)/r < 1``, ``dist(x_k) <= rho* <= r`` and
    the dense error ``|d_k|_e <= gamma = eps + S rho*``, ``a = eps_w N_w + Delta``;
    ``gamma_strict = R0 / (1 - S N)`` is the paper's comparison.
    """

    controller: str
    robust: bool
    norm: str | None = None
    cost: str | None = None
    cost_value: float | None = None
    objective: float | None = None
    strictly_proper: bool
    T: int
    S: float
    eps_e: float
    radius: float
    delta: float
    eps_w: float
    eps_b: float = 0.0
    """The bias term's bound (m/s^2 per axis; docs/guarantee.md#the-bias-term): a constant
    acceleration ``||beta||_inf <= eps_b`` besides ``||w'_k|| <= eps_w``; 0: no bias term."""
    R0: float
    m: int = 0
    eps_o: float = 0.0
    measure: str = "full"
    gate: float | None = None
    """Velocity gate ``V``: the controller reads ``clip(y_v - v_ref, -V, V)``."""
    tested_range: float | None = None
    """Largest distance at which the premise's S was tested on left-out data."""
    solver_status: str | None = None
    solver: str | None = None
    dt: float
    mass: float
    Q: list[list[float]] | None = None
    R: list[list[float]] | None = None
    closed_loop_spectral_radius: float | None = None
    closed_loop_norms: dict[str, ClosedLoopNorm] | None = None
    """A reference (static-gain) controller's true closed-loop norms: ``norm_phi_*`` are their
    ``value`` (an upper bound: horizon plus a geometric tail), ``truncated`` the ``T``-tap ones."""
    kp: list[float] | None = None
    kd: list[float] | None = None
    imitate: str | None = None
    error_model: str | None = None
    error_model_sha256: str | None = None
    controller_sha256: str
    """sha256 of the ``controller.npz`` this certificate is about."""
    premise: Premise | None = None
    """The premise the guarantee rests on, with the training data's violated shares
    (:mod:`qsls.pipeline.premise.record`)."""
    calibration: Calibration | None = None
    """The calibration behind the numbers above (``qsls calibrate``); None: the design premise."""
    promise: str | None = None
    """What the certificate promises, in one sentence: for which conditions, with which
    probability, and what lies outside (written by ``qsls calibrate``:
    :func:`qsls.pipeline.evaluate.verdict.promise`, docs/calibration.md#the-promise)."""

    @field_validator("tested_range")
    @classmethod
    def _finite_range(cls, v: float | None) -> float | None:
        if v is not None and not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{v} is not a finite non-negative distance")
        return v

    @field_validator("controller")
    @classmethod
    def _plain_name(cls, v: str) -> str:
        why = name_problem(v)
        if why is not None:
            raise ValueError(why)
        return v

    @model_serializer(mode="wrap")
    def _in_file_order(self, handler: Any) -> dict[str, Any]:
        data = handler(self)
        return {k: data[k] for k in FILE_ORDER if k in data}

    def numbers(self) -> PremiseNumbers:
        """The premise's numbers as the guarantee's arithmetic reads them (the one form every
        reader of a certificate takes: evaluate, calibrate, export and the monitor)."""
        return PremiseNumbers(
            eps=self.eps_e, S=self.S, radius=self.radius, eps_w=self.eps_w, delta=self.delta,
            eps_o=self.eps_o, m=self.m, R0=self.R0, gate=self.gate, eps_b=self.eps_b,
        )  # fmt: skip

    @classmethod
    def of(cls, body: CertificateBody, **setting: Any) -> Certificate:
        """The certificate of ``body`` against ``setting`` (controller name, the premise's
        numbers, the problem, ``controller_sha256``, ...), its keys in :data:`FILE_ORDER`."""
        return cls.model_validate({**setting, **dict(body)})

    def to_yaml(self) -> str:
        return dump_yaml(self.model_dump())

    def save(self, path: Path) -> Path:
        """Write ``path`` (a folder: ``path/certificate.yaml``) atomically."""
        f = in_folder(Path(path), CERTIFICATE_FILE)
        atomic_write_bytes(f, self.to_yaml().encode())
        return f

    @classmethod
    def load(cls, path: Path) -> Certificate:
        """Read ``certificate.yaml`` (or a folder holding it), its record checked against itself
        (:func:`record_consistency`) and, where ``controller.npz`` lies beside it, its numbers
        recomputed from those taps (:func:`load_controller_dir`'s checks); refused in one line
        otherwise."""
        f = in_folder(Path(path), CERTIFICATE_FILE)
        cert, digest = parse_certificate(f)
        verified_controller(f.parent, cert, digest, taps=(f.parent / CONTROLLER_FILE).is_file())
        return cert


def parse_certificate(f: Path) -> tuple[Certificate, str]:
    """The certificate in file ``f`` (typed, strict) and the sha256 of its bytes."""
    import yaml  # deferred: pyyaml's import is slow and only a file read needs it
    from pydantic import ValidationError  # deferred: as above, on the hot path of no caller

    if not f.is_file():
        raise InputError(
            f"{f.parent}: no {CERTIFICATE_FILE}; pass a controller folder written by "
            "'qsls synth' (one folder per controller inside the synth output)"
        )
    raw = f.read_bytes()
    try:
        data = load_yaml(raw.decode("utf-8", "replace"), f)
    except yaml.YAMLError:
        raise InputError(f"{f}: not valid YAML; regenerate it with 'qsls synth'") from None
    if not isinstance(data, dict):
        raise InputError(f"{f}: not a certificate (expected a mapping)")
    if "controller" in data:  # before the model: its own one-line message
        check_controller_name(data["controller"], f"{f}: controller")
    try:
        cert = Certificate.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise InputError(
            f"{f}: not a certificate of this qsls version ({where}: {first['msg']}); "
            "regenerate it with 'qsls synth'"
        ) from None
    return cert, hashlib.sha256(raw).hexdigest()


FILE_ORDER = (
    "controller", "status", "status_reason", "promise", "robust", "norm", "cost", "cost_value", "objective", "strictly_proper",
    "T", "S", "eps_e", "radius", "delta", "eps_w", "eps_b", "R0", "norm_phi_xx_h", "norm_phi_xy",
    "norm_phi_ux", "norm_phi_uy", "robustness_lhs", "margin", "s_times_norm_phi_xy", "a",
    "gamma", "gamma_strict", "rho_star", "norm_N", "norm_N_w", "G_m", "G_b", "m", "eps_o", "measure",
    "gate", "rho_v", "tested_range", "achievability_residual", "truncation_residual",
    "realization_error", "perturbation_peak", "perturbation_final", "checks", "solver_status",
    "solver", "dt", "mass", "Q", "R", "closed_loop_spectral_radius", "closed_loop_norms", "kp",
    "kd", "imitate", "error_model", "error_model_sha256", "controller_sha256", "premise",
    "calibration",
)  # fmt: skip
"""The keys of ``certificate.yaml`` in their order: the setting first, then what was found."""


_RECOMPUTED: dict[tuple[str, str], Controller] = {}
"""Certificates whose numbers were recomputed and matched, by (sha256 of ``certificate.yaml``,
sha256 of ``controller.npz``): the same two files are never recomputed twice in a process
(a calibration reads its candidates once per flight)."""


def verified_controller(
    folder: Path, cert: Certificate, digest: str, taps: bool = True
) -> Controller | None:
    """``folder``'s controller, once its certificate is shown to be about it: the sha256 it
    records, a ``certified`` status its own checks and record allow, a record that agrees with
    itself (:func:`record_consistency`), and every number recomputed from the taps
    (:func:`recomputation_problems`, cached per pair of files); without ``taps`` (a
    certificate read alone) all but the last, and None."""
    f = folder / CONTROLLER_FILE
    if f.is_file():  # the hash first: a damaged file is refused before it is parsed
        actual = hashlib.sha256(f.read_bytes()).hexdigest()
        if actual != cert.controller_sha256:
            raise InputError(
                f"{folder}: {CONTROLLER_FILE} (sha256 {actual[:12]}) is not the controller its "
                f"{CERTIFICATE_FILE} certifies ({cert.controller_sha256[:12]}); refusing to use it"
            )
    failed = [k for k, v in (cert.checks or {}).items() if not v["passed"]]
    why = f"failed checks {', '.join(failed)}" if failed else ""
    if not why and cert.premise is not None and not cert.premise.holds and cert.calibration is None:
        why = cert.premise.shares()  # a calibrated certificate rests on its calibration instead
    if cert.status == CERTIFIED and not why:
        why = "; ".join(calibration_problems(cert))
    if cert.status == CERTIFIED and why:
        raise InputError(
            f"{folder}: {CERTIFICATE_FILE} says 'certified' against its own record ({why}); "
            "the file was altered: regenerate it with 'qsls synth' and 'qsls calibrate'"
        )
    why_record = record_consistency(cert)
    if why_record:
        raise InputError(
            f"{folder / CERTIFICATE_FILE}: its calibration record disagrees with itself "
            f"({_first(why_record)}); the file was altered: regenerate it with 'qsls calibrate'"
        )
    if not taps:
        return None
    key = (digest, cert.controller_sha256)
    if key in _RECOMPUTED:
        return _RECOMPUTED[key]
    ctrl = Controller.load(folder)
    diffs = recomputation_problems(cert, ctrl)
    if diffs:
        raise InputError(
            f"{folder}: {CERTIFICATE_FILE} is not what its taps and premise give "
            f"({_first(diffs)}); the file was altered or written by another qsls version: "
            "regenerate it with 'qsls synth' (and 'qsls calibrate'), or run 'qsls verify'"
        )
    if len(_RECOMPUTED) > 256:
        _RECOMPUTED.clear()
    _RECOMPUTED[key] = ctrl
    return ctrl


def _first(why: list[str]) -> str:
    return why[0] + (f"; and {len(why) - 1} more" if len(why) > 1 else "")


THEOREM = (
    "norm_phi_xx_h", "norm_phi_xy", "norm_phi_ux", "norm_phi_uy", "robustness_lhs", "margin",
    "s_times_norm_phi_xy", "a", "gamma", "gamma_strict", "rho_star", "norm_N", "norm_N_w",
    "G_m", "G_b", "rho_v", "perturbation_peak",
)  # fmt: skip
"""The certificate's numbers recomputed exactly (:data:`RECOMPUTE_RTOL`): norms and the
guarantee's arithmetic are sums of absolute tap values, the perturbation peak a seeded
simulation; none depends on more than the summation order."""
RECOMPUTE_RTOL = 1e-9
"""Largest relative difference between a stored and a recomputed :data:`THEOREM` number (the
summation order moves them by about 1e-15)."""
ROUNDOFF = {
    "achievability_residual": ACHIEVABILITY_TOL, "truncation_residual": ACHIEVABILITY_TOL,
    "realization_error": REALIZATION_TOL, "perturbation_final": PERTURBATION_TOL,
}  # fmt: skip
"""Round-off residuals, each compared to within its check's limit: below the limit both are
round-off, whose digits another BLAS may change; a stored value beyond it is a failed check."""
CHECK_TOL = {
    "achievability": ACHIEVABILITY_TOL, "measured_channels": ACHIEVABILITY_TOL,
    "realization": REALIZATION_TOL, "internal_stability": PERTURBATION_TOL,
}  # fmt: skip
"""A check's value compared as :data:`ROUNDOFF`; ``robustness`` and ``gate`` as :data:`THEOREM`."""


SOLVED_AS = {"optimal": "optimal", "optimal_inaccurate": "inaccurate"}
"""The solve's status as :func:`qsls.pipeline.control.certify.certify` read it, from the
solver's own status the certificate records (``sls.Solution.status`` of
``solver_status``): the only two under which a solve returns taps."""


def recomputed_body(cert: Certificate, ctrl: Controller) -> CertificateBody:
    """:func:`qsls.pipeline.control.certify.certify` on ``ctrl``'s taps under ``cert``'s premise
    (for a calibrated certificate the inflated one it states), in its weights: what the file
    must say (docs/verify.md)."""
    numbers = cert.numbers()
    shape = premise_shape(numbers, cert.premise, cert.measure, ctrl.model.nx)  # synth's shape
    return certify(
        ctrl.taps, ctrl.model, numbers, shape,
        solver_status=SOLVED_AS.get(cert.solver_status or "optimal", cert.solver_status or ""),
        reference=cert.status == REFERENCE,
    )  # fmt: skip


def differs(have: Any, want: Any, rtol: float = RECOMPUTE_RTOL, atol: float = 1e-12) -> bool:
    """A stored value ``have`` is not the recomputed ``want``: None only equals None, NaN only
    NaN, an infinity only itself, numbers within ``rtol`` (relative) or ``atol``."""
    if have is None or want is None or isinstance(have, str) or isinstance(want, str):
        return have != want
    if isinstance(have, bool) or isinstance(want, bool):
        return have is not want
    h, w = float(have), float(want)
    if math.isnan(h) or math.isnan(w):
        return not (math.isnan(h) and math.isnan(w))
    if math.isinf(h) or math.isinf(w):
        return h != w
    return abs(h - w) > max(rtol * max(abs(h), abs(w)), atol)


def _shown(v: Any) -> str:
    return f"{v:.10g}" if isinstance(v, float) and not isinstance(v, bool) else repr(v)


def recomputation_problems(cert: Certificate, ctrl: Controller) -> list[str]:
    """Each number of ``cert`` its taps and premise do not give: ``"<field> stored <v>,
    recomputed <v>"`` (:func:`recomputed_body`); the checks' values and ``passed`` likewise, a
    check the recomputation has and the file lacks, a status that claims checks the taps fail,
    and a calibration whose ``holds`` the taps contradict. A static gain (the PD) has true
    closed-loop norms, not its taps' (docs/synthesis.md): only its ``reference`` status is
    checked. Empty when the file is what its taps give."""
    if ctrl.kind == "static_gain":
        if cert.status != REFERENCE:
            return [f"status stored {cert.status!r}, a static gain is a 'reference'"]
        return []
    body = recomputed_body(cert, ctrl)
    out = []
    for k in THEOREM:
        if differs(getattr(cert, k), getattr(body, k)):
            out.append(
                f"{k} stored {_shown(getattr(cert, k))}, recomputed {_shown(getattr(body, k))}"
            )
    for k, tol in ROUNDOFF.items():
        have, want = getattr(cert, k), getattr(body, k)
        if differs(have, want, rtol=0.0, atol=tol):
            out.append(f"{k} stored {_shown(have)}, recomputed {_shown(want)}")
    stored = cert.checks or {}
    for name, want in (body.checks or {}).items():
        have = stored.get(name)
        if have is None:
            out.append(f"checks.{name} stored none, recomputed {_shown(want['value'])}")
            continue
        if have["passed"] is not want["passed"]:
            out.append(f"checks.{name}.passed stored {have['passed']}, recomputed {want['passed']}")
        roundoff = CHECK_TOL.get(name)
        rtol, atol = (0.0, roundoff) if roundoff is not None else (RECOMPUTE_RTOL, 1e-12)
        if differs(have.get("value"), want["value"], rtol, atol):
            out.append(
                f"checks.{name}.value stored {_shown(have.get('value'))}, "
                f"recomputed {_shown(want['value'])}"
            )
    claims = cert.status not in (body.status, "failed", "solver_inaccurate")
    if claims and body.status in ("failed", "solver_inaccurate"):
        out.append(f"status stored {cert.status!r}, recomputed {body.status!r}")
    c = cert.calibration
    robust_ok = bool((body.checks or {}).get("robustness", {}).get("passed", False))
    if c is not None and math.isfinite(c.lambda_hat) and c.holds is not robust_ok:
        out.append(f"calibration.holds stored {c.holds}, recomputed {robust_ok}")
    if cert.status in (CERTIFIED, EXTRAPOLATED) and not robust_ok:
        out.append(f"status stored {cert.status!r}, but the taps fail the robustness condition")
    return out


def record_consistency(cert: Certificate) -> list[str]:
    """What a certificate's calibration record says against itself or against the certificate
    (docs/verify.md), without the flights: the top-level ``tested_range`` is the record's, the
    record's ``duration_s`` its conditions' ``duration_s``, the counts its lists' lengths,
    ``rank`` and ``lambda_hat`` the calibrated quantile of its scores (exactly, not at least),
    the premise the record's design premise inflated by ``lambda_hat``, and a ``certified``
    status with no reason not to be. Empty for a certificate without a calibration."""
    c = cert.calibration
    if c is None:
        return []
    out = []
    if differs(cert.tested_range, c.tested_range):
        out.append(f"tested_range stored {cert.tested_range}, the record's {c.tested_range}")
    dur = c.conditions.get("duration_s")
    if isinstance(dur, int | float) and differs(c.duration_s, float(dur)):
        out.append(f"duration_s {c.duration_s:g}, the conditions' duration_s {dur:g}")
    if c.flights != len(c.scores):
        out.append(f"flights {c.flights} with {len(c.scores)} scores")
    if c.range_flights != len(c.range_scores):
        out.append(f"range_flights {c.range_flights} with {len(c.range_scores)} range scores")
    if c.evidence:
        roles = [e.role for e in c.evidence]
        for role, n in (("calibration", c.flights), ("range", c.range_flights)):
            if roles.count(role) != n:
                out.append(f"{roles.count(role)} {role} tick logs listed for {n} {role} flights")
    method: Literal["conformal", "pac"] = "pac" if c.method == "pac" else "conformal"
    # 1 - (1 - delta) may come back a hair below delta (record_problems does the same)
    delta = 1.0 - c.confidence + 1e-12 if c.confidence is not None else 0.05
    if c.flights and c.rank != calibration_rank(c.flights, c.alpha, method, delta):
        out.append(f"rank {c.rank}, the calibration's rank of {c.flights} flights is another")
    lam = calibrated_quantile(c.scores, c.alpha, method, delta) if c.scores else math.inf
    if c.range_scores:
        lam = max(lam, calibrated_quantile(c.range_scores, c.alpha, method, delta))
    if differs(c.lambda_hat, lam):
        out.append(f"lambda_hat stored {_shown(c.lambda_hat)}, its scores' quantile {_shown(lam)}")
    if math.isfinite(c.lambda_hat):
        out += _inflation_problems(cert)
    if cert.status == CERTIFIED and cert.status_reason:
        out.append(f"status 'certified' with a reason not to be: {cert.status_reason[:60]!r}")
    return out


def _inflation_problems(cert: Certificate) -> list[str]:
    """The certificate's premise is the record's design premise inflated by ``lambda_hat``
    (:func:`qsls.pipeline.control.calibration.inflate`), where the record states it."""
    c = cert.calibration
    assert c is not None
    lam, why = c.lambda_hat, []
    for key, have in (("eps_e", cert.eps_e), ("S", cert.S), ("eps_w", cert.eps_w),
                      ("delta", cert.delta), ("eps_b", cert.eps_b)):  # fmt: skip
        want = c.nominal.get(key)
        if want is not None and not math.isclose(have, want * lam, rel_tol=1e-9, abs_tol=1e-12):
            why.append(f"{key} {have:.6g} is not the design's {want:.6g} x lambda_hat {lam:.6g}")
    m0 = c.nominal.get("m")
    if m0 is not None and cert.m != math.floor(lam * m0 + 1e-9):
        why.append(f"m {cert.m} is not floor(lambda_hat x the design's {m0:g})")
    return why


def calibration_problems(cert: Certificate) -> list[str]:
    """Why ``cert``'s calibration record cannot back a ``certified`` status (none recorded,
    or :func:`record_problems`); empty when it can."""
    c = cert.calibration
    if c is None:
        return ["no calibration: only flights the design never saw certify (qsls calibrate)"]
    why = record_problems(
        flights=c.flights, alpha=c.alpha, method=c.method, confidence=c.confidence,
        scores=c.scores, range_scores=c.range_scores, lambda_hat=c.lambda_hat, holds=c.holds,
        shared_seeds=sorted(set(c.seeds) & set(c.design_seeds)),
        rho_star=cert.rho_star, tested_range=cert.tested_range,
    )  # fmt: skip
    # the certificate's numbers are the record's design premise inflated by lambda_hat
    why += _inflation_problems(cert) if math.isfinite(c.lambda_hat) else []
    if not (cert.robustness_lhs <= 1.0 and cert.rho_star is not None
            and cert.rho_star <= cert.radius * (1 + 1e-12)):  # fmt: skip
        why.append(f"robustness lhs {cert.robustness_lhs:.6g} or rho* {cert.rho_star} beyond r")
    return why
