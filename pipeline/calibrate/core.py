"""The calibration's arithmetic, pure (docs/calibration.md#the-packages-shape): tick logs and a
candidate's premise in; scores, the quantile, the decision and the calibrated certificate out.
No file is read or written here and nothing is flown (:mod:`qsls.pipeline.calibrate.flights`
flies or reads the flights, :mod:`qsls.pipeline.calibrate.stage` reads and writes the folders).

Each calibration flight ``f``, flown by the candidate itself under the stated conditions, gets
a score ``lambda_f``: the smallest inflation of the premise that the flight satisfies,

    lambda_f = max( max_k |d_k|_e / (eps + S dist(x_k))       over dist(x_k) <= r,
                    max_k ||H^-1 w_k||_inf / eps_w,
                    max_k dist(x_ref,k) / Delta,
                    max window count / m ),

so the flight satisfies ``P(lambda)`` (:func:`qsls.pipeline.control.calibration.inflate`) for
every ``lambda >= lambda_f``. ``lambda_hat`` is the scores' calibrated quantile
(:mod:`qsls.pipeline.control.conformal`); :func:`decide` turns it into a status:
``certified`` needs the condition under ``P(lambda_hat)``, ``flights >= 19``,
``alpha <= 0.1`` and the tested range to reach ``rho*`` (else ``extrapolated``); anything else
is ``relaxed``, with the reason.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from qsls.pipeline.calibrate.options import MonitorOptions
from qsls.pipeline.control import conformal, guarantee
from qsls.pipeline.control.artifacts import (
    Calibration,
    Certificate,
    ControllerDir,
    FlightEvidence,
    calibration_problems,
)
from qsls.pipeline.control.calibration import (
    QUANTITIES,
    Check,
    Responses,
    check,
    inflate,
    largest_value,
    tolerance,
)
from qsls.pipeline.control.guarantee import measured_channels, outlier_channels, system_norms
from qsls.pipeline.control.innovation import monitor_calibration
from qsls.pipeline.control.monitor import hover_input, sound_innovation_of
from qsls.pipeline.control.status import CERTIFIED, EXTRAPOLATED, RELAXED
from qsls.pipeline.errormodel.disturbance import ratio
from qsls.pipeline.evaluate.assumptions import CertifiedPremise, FlownLog, signals
from qsls.pipeline.evaluate.verdict import promise
from qsls.pipeline.premise.numbers import PremiseNumbers

SCORED = ("dense", "disturbance", "reference", "outliers")
"""The premise quantities a flight's score inflates, in the order the score table lists them."""
NO_INFLATION = "a calibration flight broke a premise quantity no inflation covers"
"""The start of the refusal when ``lambda_hat`` is infinite (the quantities follow it)."""


# --------------------------------------------------------------------------- scores
def flight_score(parts: Mapping[str, float]) -> float:
    """``lambda_f``: the largest of a flight's per-quantity ratios (module docstring)."""
    return max((float(parts[k]) for k in SCORED if k in parts), default=0.0)


def score_flight(
    log: FlownLog, c: CertifiedPremise, distance: Callable[[np.ndarray], np.ndarray]
) -> dict[str, float]:
    """The flight's ratio for each premise quantity and its score ``lambda_f``, with what the
    flight reached:

    - ``dense``: ``max |d_k|_e / (eps + S dist(x_k))`` over the samples within ``r``;
    - ``disturbance``: ``max ||H^-1 w_k||_inf / eps_w``; with a bias term the smallest
      inflation of ``(eps_w, eps_b)`` that holds (``split_bias``: one constant ``beta``);
    - ``reference``: ``max dist(x_ref,k) / Delta``;
    - ``outliers``: the largest outlier count in ``T`` consecutive ticks over ``m`` (inf when
      an outlier exceeds ``eps_o``, which the gate fixes and no inflation moves);
    - ``reached``: the largest ``dist(x_k)`` within ``r``, where the flight tested the dense
      premise (beyond ``r`` the premise claims nothing).
    """
    sig = signals(log, c, distance)
    dense, mag, dist, w, counts = sig.dense, sig.mag, sig.dist, sig.w, sig.counts
    inside = dist <= c.numbers.radius
    allowed = guarantee.premise_bound(c.numbers.eps, c.numbers.S, dist)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(dense > 0, dense / allowed, 0.0)
    ref_max = float(distance(log.ref).max())
    outliers = math.inf if mag.max() > c.numbers.eps_o else ratio(float(counts.max()), c.numbers.m)
    parts = {
        "dense": float(rel[inside].max()) if inside.any() else 0.0,
        "disturbance": sig.split.ratio,
        "reference": ratio(ref_max, c.numbers.delta),
        "outliers": outliers,
    }
    # reached: where the dense premise was scored (within r; a flight that went further passed
    # through every distance up to r on the way)
    return {
        **parts,
        "score": flight_score(parts),
        "reached": float(dist[inside].max()) if inside.any() else 0.0,
        "w_max": float(w.max()) if len(w) else 0.0,
        "window_max": float(counts.max()),
        "ref_max": ref_max,
        "outlier_max": float(mag.max()),
        "bias": float(np.abs(sig.split.beta).max()),
    }


def range_score(parts: Mapping[str, float]) -> float:
    """A range flight's score: ``max(dense, disturbance, outliers)``. Its reference is offset on
    purpose, so the reference term (``dist(x_ref) / Delta``) is left out; the disturbance stays
    in: ``||H^-1 w_k|| <= eps_w`` is assumed at every state out to ``rho*``, and a range flight
    is where the states far from the training data are (docs/calibration.md, Tested range)."""
    return max(parts["dense"], parts["disturbance"], parts["outliers"])


def scored(
    log: FlownLog, c: CertifiedPremise, distance: Callable[[np.ndarray], np.ndarray], role: str
) -> dict[str, float]:
    """:func:`score_flight`, a range flight's score its :func:`range_score` (the offset is the
    point: every part but the reference's)."""
    parts = score_flight(log, c, distance)
    if role == "range":
        parts["score"] = range_score(parts)
    return parts


def set_by(rows: Sequence[Mapping[str, Any]], lambda_hat: float) -> str:
    """Which premise quantity set ``lambda_hat``: the largest part (:data:`SCORED`) of the
    flight whose score is ``lambda_hat`` (the quantile's flight; the first in ``rows`` on a
    tie), with its role, e.g. ``"reference (calibration flight)"``; ``''`` when no flight's
    score is ``lambda_hat`` (a hand-made record)."""
    for r in rows:
        score = float(r.get("score", math.nan))
        if math.isfinite(lambda_hat) and math.isclose(score, lambda_hat, rel_tol=1e-12):
            # a range flight's score leaves the reference's term out (its offset is the point)
            keys = [
                k for k in SCORED if k in r and not (k == "reference" and r.get("role") == "range")
            ]
            part = max(keys, key=lambda k: float(r[k]), default="")
            return f"{part} ({r.get('role', 'calibration')} flight)" if part else ""
    return ""


# --------------------------------------------------------------------------- the decision
@dataclass(frozen=True)
class Rule:
    """The statement a calibration makes: ``alpha``, the quantile's method, PAC's ``delta``."""

    alpha: float
    method: conformal.Method = "conformal"
    delta: float = 0.05

    @classmethod
    def of_options(cls, options: Any) -> Rule:
        """The rule a calibration's options ask for (``alpha``, ``method``, ``delta``)."""
        return cls(options.alpha, options.method, options.delta)

    @classmethod
    def of_record(cls, c: Calibration) -> Rule:
        """The rule a calibration record states (``confidence`` is ``1 - delta``)."""
        method: conformal.Method = "pac" if c.method == "pac" else "conformal"
        return cls(c.alpha, method, 1.0 - c.confidence if c.confidence is not None else 0.05)

    def rank(self, n: int) -> int:
        return conformal.calibration_rank(n, self.alpha, self.method, self.delta)

    def quantile(self, scores: Sequence[float]) -> float:
        return conformal.calibrated_quantile(scores, self.alpha, self.method, self.delta)


@dataclass(frozen=True)
class Scores:
    """What one candidate's flights in one condition gave the decision."""

    calibration: tuple[float, ...]
    range: tuple[float, ...] = ()
    reached: tuple[float, ...] = ()
    """Every calibration and range flight's ``reached``."""
    crashed: int = 0
    broken: tuple[Mapping[str, Any], ...] = ()
    """The score rows whose score is inf (the refusal names their quantities)."""

    @classmethod
    def of(cls, rows: Sequence[Mapping[str, Any]]) -> Scores:
        """From score rows (``role``, ``score``, ``reached``, ``crashed``), in their order."""
        return cls(
            calibration=tuple(float(r["score"]) for r in rows if r["role"] == "calibration"),
            range=tuple(float(r["score"]) for r in rows if r["role"] == "range"),
            reached=tuple(float(r["reached"]) for r in rows),
            crashed=sum(bool(r.get("crashed", False)) for r in rows),
            broken=tuple(r for r in rows if math.isinf(float(r["score"]))),
        )


@dataclass(frozen=True)
class Outcome:
    """What :func:`decide` finds of a candidate's :class:`Scores` (module docstring)."""

    status: str
    reason: str
    lambda_hat: float
    rank: int
    check: Check | None
    """The condition under the premise inflated by ``lambda_hat`` (None: no finite one)."""
    tested_range: float
    tolerances: dict[str, float]
    scores: Scores


def decide(s: Scores, nominal: PremiseNumbers, taps: Responses, rule: Rule) -> Outcome:
    """The candidate's :class:`Outcome`: ``lambda_hat`` the larger of the calibration scores'
    and the range scores' quantiles (the range flights can only raise it), the condition under
    ``P(lambda_hat)`` on the fixed taps, then the status rule (module docstring)."""
    n = len(s.calibration)
    lam = rule.quantile(s.calibration)
    if s.range:
        lam = max(lam, rule.quantile(s.range))
    tested = float(max(s.reached, default=0.0))

    def outcome(status: str, why: str, chk: Check | None, tol: dict[str, float]) -> Outcome:
        return Outcome(status, why, lam, rule.rank(n), chk, tested, tol, s)

    if not math.isfinite(lam):
        return outcome(RELAXED, _no_quantile(s, nominal, rule), None, {})
    inflated = inflate(nominal, lam)
    chk = check(inflated, taps)
    tol = _tolerances(inflated, taps) if chk.holds else {}
    reasons = _not_certified(s, chk, lam, nominal, rule)
    if reasons:
        return outcome(RELAXED, "; ".join(reasons), chk, tol)
    rho = chk.guarantee.rho_star
    if tested < rho:
        why = (
            f"the flights reached dist {tested:.3g} from the training states while the "
            f"certificate uses the premise out to rho* {rho:.3g}: add range flights over a "
            "tube that reaches it (--range-flights N --tube R; calibrate.range_flights, "
            "calibrate.tube in a config)"
        )
        return outcome(EXTRAPOLATED, why, chk, tol)
    return outcome(CERTIFIED, "", chk, tol)


def _no_quantile(s: Scores, nominal: PremiseNumbers, rule: Rule) -> str:
    """Why ``lambda_hat`` is infinite: too few flights for ``alpha``, or a flight that broke a
    quantity no inflation covers."""
    need = conformal.smallest_flights(rule.alpha, rule.method, rule.delta)
    least = conformal.MIN_FLIGHTS
    short = [
        f"{k} {what} flights"
        for k, what in ((len(s.calibration), "calibration"), (len(s.range), "range"))
        if k and rule.rank(k) > k
    ]
    if not short:
        return broken_premise(s.broken, nominal)
    return (
        f"{' and '.join(short)} cannot support alpha {rule.alpha:g} ({rule.method} "
        f"needs {need} for any calibrated premise, certified needs {least}: "
        f"--flights {max(need, least)})"
    )


def _tolerances(inflated: PremiseNumbers, taps: Responses) -> dict[str, float]:
    """Each quantity's tolerance; a quantity stated as 0 has an infinite factor: its largest
    value instead."""
    tol = {q: tolerance(inflated, taps, q) for q in QUANTITIES}
    return tol | {
        f"{q}_max": largest_value(inflated, taps, q)
        for q in QUANTITIES
        if q != "m" and float(getattr(inflated, q)) == 0.0
    }


def _not_certified(
    s: Scores, chk: Check, lam: float, nominal: PremiseNumbers, rule: Rule
) -> list[str]:
    """What makes a finite calibration ``relaxed``."""
    reasons = []
    if s.crashed:
        reasons.append(f"{s.crashed} calibration flight(s) crashed")
    if not chk.holds:
        g = chk.guarantee
        gate = (
            f", rho_v {chk.rho_v:.3g} against the gate {nominal.gate:g})"
            if chk.rho_v is not None
            else ")"
        )
        reasons.append(
            f"the taps fail the robustness condition under the premise inflated by "
            f"lambda_hat {lam:.3g} (lhs {g.robustness_lhs:.3g}, rho* "
            f"{g.rho_star:.3g} against r {nominal.radius:g}" + gate
        )
    n = len(s.calibration)
    if n < conformal.MIN_FLIGHTS:
        reasons.append(f"{n} calibration flights (certified needs {conformal.MIN_FLIGHTS})")
    if rule.alpha > conformal.MAX_ALPHA:
        reasons.append(f"alpha {rule.alpha:g} > {conformal.MAX_ALPHA:g}")
    return reasons


# --------------------------------------------------------------------------- why no inflation
def _value(row: Mapping[str, Any], key: str) -> float | None:
    v = row.get(key)
    return float(v) if isinstance(v, int | float) and math.isfinite(float(v)) else None


def _what(quantity: str, rows: Sequence[Mapping[str, Any]], p: PremiseNumbers) -> str:
    """One quantity's clause: what it measured (the largest over ``rows``), against what, and
    the fix."""

    def top(key: str) -> str:
        vals = [v for r in rows if (v := _value(r, key)) is not None]
        return f"{max(vals):.3g}" if vals else "above 0"

    if quantity == "reference":
        return (
            f"reference: dist(x_ref) reaches {top('ref_max')} over Delta {p.delta:g} (an error "
            "model fitted without a reference): refit with qsls fit --reference (the reference "
            "flown) or state Delta with qsls synth --delta"
        )
    if quantity == "disturbance":
        return (
            f"disturbance: ||H^-1 w|| reaches {top('w_max')} over eps_w {p.eps_w:g}; state "
            "the disturbance bound (qsls synth --eps-w)"
        )
    if quantity == "outliers":
        if p.m == 0 and any((_value(r, "window_max") or 0) > 0 for r in rows):
            return (
                f"outliers: {top('window_max')} outliers in a window of T ticks over m 0; "
                "allow them (qsls synth --m)"
            )
        return (
            f"outliers: an outlier of {top('outlier_max')} exceeds eps_o {p.eps_o:g}, which "
            "the gate fixes and no inflation moves; raise the bound (qsls synth --eps-o, "
            "--gate)"
        )
    return (
        f"dense: the error is not 0 where eps + S dist is (eps {p.eps:g}, S {p.S:g}); state "
        "the error bound (qsls synth --eps-e, --S)"
    )


def broken_premise(rows: Sequence[Mapping[str, Any]], nominal: PremiseNumbers) -> str:
    """The refusal of a calibration whose ``lambda_hat`` is infinite because of flights
    ``rows`` (their parts, :data:`SCORED`, and what they measured: ``ref_max``, ``w_max``,
    ``window_max``, ``outlier_max``; docs/calibration.md#no-inflation-covers): each infinite
    part once, with its largest value over the flights, the stated limit and the fix, e.g.
    ``reference: dist(x_ref) reaches 0.52 over Delta 0: ... (qsls fit --reference ...)``.
    A part is infinite when the certificate states a limit of 0 that the flight exceeds, or
    when one outlier exceeds ``eps_o`` (the gate fixes it; no inflation moves it)."""
    inf = [q for q in SCORED if any(math.isinf(float(r.get(q, 0.0) or 0.0)) for r in rows)]
    if not inf:
        return NO_INFLATION
    clauses = []
    for q in inf:
        hit = [r for r in rows if math.isinf(float(r.get(q, 0.0) or 0.0))]
        n = f" ({len(hit)} flight{'s' if len(hit) != 1 else ''})"
        clauses.append(_what(q, hit, nominal).replace(":", n + ":", 1))
    return f"{NO_INFLATION}: " + "; ".join(clauses)


# --------------------------------------------------------------------------- the certificate
def responses(d: ControllerDir) -> Responses:
    """What the condition needs of the candidate's taps, in its certificate's weights."""
    c, p = d.certificate, d.certificate.premise
    taps, model = d.controller.taps, d.controller.model
    extra = model.nx - 6  # the attitude plant's states: unweighted, error-free
    sx = (*(p.state_scale if p is not None else (1.0,) * 6), *(0.0,) * extra)
    se = (*(p.error_scale if p is not None else (1.0,) * 6), *(1.0,) * extra)
    measured = measured_channels(c.measure)
    outlier = outlier_channels(c.measure, 1)  # G_m is recomputed per m
    phi_xx_h = taps.Phi_xx @ model.H
    dirs = model.bias_dirs
    norms = system_norms(
        taps.Phi_xy, phi_xx_h, state_scale=sx, error_scale=se, measured=measured, bias_dirs=dirs
    )
    return Responses(taps.Phi_xy, phi_xx_h, sx, se, measured, outlier, norms, dirs)


def nominal_record(p: PremiseNumbers, rho_star: float | None) -> dict[str, float | None]:
    """The record's ``nominal``: the design premise ``p`` (and its ``rho*``) in the
    certificate file's spelling."""
    return {
        "eps_e": p.eps,
        "S": p.S,
        "eps_w": p.eps_w,
        "delta": p.delta,
        "m": float(p.m),
        "rho_star": rho_star,
        "eps_b": p.eps_b,
    }


def nominal_numbers(cert: Certificate) -> PremiseNumbers | None:
    """The design premise a calibrated certificate's record states (:func:`nominal_record`
    read back; radius, ``eps_o`` and the gate are not inflated: the certificate's); None where
    the record does not state one."""
    c = cert.calibration
    nom = c.nominal if c is not None else {}
    keys = ("eps_e", "S", "eps_w", "delta", "m", "rho_star")
    if any(not isinstance(nom.get(k), int | float) for k in keys):
        return None
    return PremiseNumbers(
        eps=float(nom["eps_e"] or 0.0),
        S=float(nom["S"] or 0.0),
        radius=cert.radius,
        eps_w=float(nom["eps_w"] or 0.0),
        delta=float(nom["delta"] or 0.0),
        eps_o=cert.eps_o,
        m=int(nom["m"] or 0),
        R0=None,
        gate=cert.gate,
        eps_b=float(nom.get("eps_b") or 0.0),
    )


def calibrated_checks(
    design: dict[str, dict[str, Any]] | None, chk: Check
) -> dict[str, dict[str, Any]]:
    """The certificate's checks with the robustness condition (and the gate) read under the
    calibrated premise, as the calibrated status is; each keeps its design value beside."""
    out = {k: dict(v) for k, v in (design or {}).items()}
    g = chk.guarantee
    if "robustness" in out:
        out["robustness"] |= {
            "design_value": out["robustness"].get("value"),
            "value": g.robustness_lhs,
            "passed": bool(chk.holds),
        }
    if "gate" in out and chk.rho_v is not None:
        out["gate"] |= {
            "design_value": out["gate"].get("value"),
            "value": chk.rho_v,
            "passed": bool(chk.rho_v <= float(out["gate"]["limit"]) * (1 + 1e-7)),
        }
    return out


@dataclass(frozen=True)
class Record:
    """What a calibration record states besides its :class:`Outcome`: the rule, the
    conditions and the flights behind it."""

    rule: Rule
    conditions: dict[str, Any]
    duration_s: float
    seeds: tuple[int, ...] = ()
    """The calibration flights' seeds (simulated flights; none for recorded ones)."""
    design_seeds: tuple[int, ...] = ()
    evidence_seeds: tuple[int, ...] = ()
    parts: tuple[Mapping[str, Any], ...] = ()
    """The calibration flights' score rows (the record keeps each quantity's largest part)."""
    logs: tuple[str, ...] = ()
    """Recorded calibration flights: each vehicle log's sha256."""
    evidence: tuple[FlightEvidence, ...] = ()


def calibrated_certificate(
    cert: Certificate, nominal: CertifiedPremise, o: Outcome, r: Record
) -> Certificate:
    """``cert`` calibrated: the inflated premise's numbers, the status and the ``calibration``
    record of ``o`` and ``r``, under the design premise ``nominal``."""
    record = Calibration(
        flights=len(o.scores.calibration),
        alpha=r.rule.alpha,
        confidence=1.0 - r.rule.delta if r.rule.method == "pac" else None,
        method=r.rule.method,
        conditions=r.conditions,
        duration_s=r.duration_s,
        seeds=list(r.seeds),
        design_seeds=list(r.design_seeds),
        evidence_seeds=list(r.evidence_seeds),
        scores=list(o.scores.calibration),
        lambda_hat=o.lambda_hat,
        rank=o.rank,
        tested_range=o.tested_range,
        nominal=nominal_record(nominal.numbers, nominal.rho_star),
        parts={k: float(max((p[k] for p in r.parts), default=0.0)) for k in SCORED},
        tolerances=o.tolerances,
        holds=bool(o.check is not None and o.check.holds),
        range_flights=len(o.scores.range),
        range_scores=list(o.scores.range),
        logs=list(r.logs),
        evidence=list(r.evidence),
    )
    update: dict[str, Any] = {
        "status": o.status,
        "status_reason": o.reason or None,
        "calibration": record,
        "tested_range": o.tested_range,
    }
    if o.check is not None:
        update |= _inflated(cert, o.check)
    new = cert.model_copy(update=update)
    new = new.model_copy(update={"promise": promise(new.model_dump())})
    Certificate.model_validate(new.model_dump())  # the record must read back
    if new.status == CERTIFIED and (why := calibration_problems(new)):
        raise RuntimeError(f"{cert.controller}: a certified record its readers would refuse: {why}")
    return new


def _inflated(cert: Certificate, chk: Check) -> dict[str, Any]:
    """The certificate's numbers under the premise ``chk`` read."""
    p, g = chk.premise, chk.guarantee
    return {
        "eps_e": p.eps,
        "S": p.S,
        "eps_w": p.eps_w,
        "delta": p.delta,
        "m": p.m,
        "eps_b": p.eps_b,
        "robustness_lhs": g.robustness_lhs,
        "margin": g.margin,
        "a": g.a,
        "rho_star": g.rho_star,
        "gamma": g.dense_bound,
        # the paper's comparison R0 / (1 - S N) under the calibrated premise: R0 is its
        # error bound (the design's R0 was the design premise's)
        "R0": p.eps if p.R0 is None else p.R0,
        "gamma_strict": g.gamma_strict,
        "s_times_norm_phi_xy": g.s_times_n,
        "G_m": chk.G_m,
        "rho_v": chk.rho_v if chk.rho_v is not None else cert.rho_v,
        "checks": calibrated_checks(cert.checks, chk),
    }


def with_monitor(
    d: ControllerDir, logs: Sequence[FlownLog], monitor: MonitorOptions
) -> Certificate:
    """``d``'s certificate with the innovation monitor's calibration in its record
    (docs/monitor.md#the-calibrated-mode): each calibration flight's statistic (``logs``, in
    the order of the scores) under the certificate's sound monitor, their conformal quantile
    at the option's false-trip rate, and the mode
    (:func:`qsls.pipeline.control.innovation.monitor_calibration`); unchanged where that
    monitor is off."""
    cert, spec = d.certificate, sound_innovation_of(d)
    if cert.calibration is None or not spec.active:
        return cert
    rate = monitor.false_trip_rate
    rec = monitor_calibration(spec, logs, hover_input(d), cert.gate, monitor.mode, rate)
    record = cert.calibration.model_copy(update={"monitor": rec})
    return cert.model_copy(update={"calibration": record})


def with_evidence(cert: Certificate, more: Sequence[FlightEvidence]) -> Certificate:
    """``cert`` with ``more`` (the validation flights' tick logs) appended to its record."""
    c = cert.calibration
    if c is None or not more:
        return cert
    record = c.model_copy(update={"evidence": [*c.evidence, *more]})
    return cert.model_copy(update={"calibration": record})
