"""What a generated file says about its guarantee: the generalized theorem in the certificate's
own weights (docs/guarantee.md, The claim), or, for a controller without one, that it has none
and why, in the first line.

The lines are plain text; :mod:`qsls.pipeline.export.c` and :mod:`qsls.pipeline.export.python`
put them in a comment and a docstring, each through its escape (:func:`c_comment`,
:func:`c_string`, :func:`py_doc`): a certificate's texts (the controller's name, a status
reason, calibration conditions, check names) come from a file that may have been shared, and
nothing in them may end the comment, the string or the docstring (docs/export.md).
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.control.artifacts import Calibration, Certificate, ControllerDir
from qsls.pipeline.control.innovation import InnovationSpec
from qsls.pipeline.control.monitor import COUNT, OFF, TRIP, MonitorSpec, innovation_of
from qsls.pipeline.control.status import CERTIFIED, RELAXED

CHANNELS = ("px", "py", "pz", "vx", "vy", "vz")


def _g(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.6g}"


def _diag(v: Any) -> str:
    return "diag(" + ", ".join(f"{float(x):g}" for x in v) + ")"


def _escaped(ch: str) -> str:
    """``\\xNN``, ``\\uNNNN`` or ``\\UNNNNNNNN``: a character outside printable ASCII, as text."""
    o = ord(ch)
    return f"\\x{o:02x}" if o < 0x100 else f"\\u{o:04x}" if o < 0x10000 else f"\\U{o:08x}"


def _printable(ch: str) -> bool:
    return 0x20 <= ord(ch) < 0x7F


def c_comment(text: str) -> str:
    """``text`` safe inside a C block comment: a backslash doubled, every character outside
    printable ASCII (a newline, a bidirectional override) written ``\\xNN`` / ``\\uNNNN``,
    ``*/`` and ``/*`` split by a space (no end of the comment, no nested-comment warning) and
    a backslash put between two ``?`` (no trigraph such as ``??/``, C99's backslash)."""
    out = "".join("\\\\" if ch == "\\" else ch if _printable(ch) else _escaped(ch) for ch in text)
    out = out.replace("*/", "* /").replace("/*", "/ *")
    return re.sub(r"\?(?=\?)", "?\\\\", out)


def c_string(text: str) -> str:
    """The body of a C string literal reading back as ``text``'s UTF-8 bytes: ``"``, ``\\``
    and ``?`` escaped (no trigraph), every byte outside printable ASCII in octal."""
    out = []
    for b in text.encode("utf-8", "backslashreplace"):
        ch = chr(b)
        out.append("\\" + ch if ch in '"\\?' else ch if _printable(ch) else f"\\{b:03o}")
    return "".join(out)


def py_doc(text: str) -> str:
    """``text`` safe inside a (non-raw) Python docstring: a backslash and every ``"`` escaped
    (so no ``\"\"\"`` can end it), every character outside printable ASCII written as its
    escape (``\\n``: no new line in the source)."""
    return "".join(
        "\\" + ch if ch in '"\\' else ch if _printable(ch) else _escaped(ch) for ch in text
    )


def wrap_lines(lines: tuple[str, ...] | list[str], lead: str, width: int = 96) -> str:
    """``lines`` wrapped to ``width``, each output line starting with ``lead`` (continuations
    indented four more than their line)."""
    import textwrap

    out: list[str] = []
    for line in lines:
        indent = " " * (len(line) - len(line.lstrip()))
        out += textwrap.wrap(
            line, width - len(lead), subsequent_indent=indent + "    ",
            break_long_words=False, break_on_hyphens=False,
        ) or [""]  # fmt: skip
    return "\n".join((lead + x).rstrip() for x in out)


def has_guarantee(cert: Certificate) -> bool:
    """A certificate that states a guarantee: certified, robust, ``rho*`` finite and within ``r``."""
    return (
        cert.status == CERTIFIED
        and cert.robust
        and cert.rho_star is not None
        and math.isfinite(cert.rho_star)
        and cert.rho_star <= cert.radius * (1 + 1e-12)
    )


def first_line(cert: Certificate, reason: str) -> str:
    """``CERTIFIED ...`` or ``NOT CERTIFIED ... no guarantee; missing: ...`` (``reason`` from
    :func:`qsls.pipeline.export.bank.status_reason`)."""
    if has_guarantee(cert):
        return (
            f"CERTIFIED controller {cert.controller}: the guarantee below holds under its premise"
        )
    return (
        f"NOT CERTIFIED (status {cert.status}, exported with --allow-uncertified): "
        f"NO GUARANTEE; missing: {reason}"
    )


def _condition(v: Any) -> str:
    """One calibration condition as text: the reference and the vehicle in full (a
    certificate says nothing about another reference family or vehicle)."""
    if isinstance(v, dict):
        return "(" + ", ".join(f"{k} {_condition(x)}" for k, x in v.items() if x is not None) + ")"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_condition(x) for x in v) + "]"
    return f"{v:g}" if isinstance(v, float) else str(v)


def _calibration_lines(cal: Calibration | None) -> list[str]:
    if cal is None:
        return [
            "calibration: no calibration (the premise describes the training flights; no "
            "calibration flights were flown by this controller)"
        ]
    conf = (f"confidence {cal.confidence:g}" if cal.confidence is not None
            else "marginal over the calibration draw")  # fmt: skip
    cond = ", ".join(f"{k} {_condition(v)}" for k, v in cal.conditions.items() if v is not None)
    return [
        f"calibration: {cal.flights} flights flown by this controller ({cal.method}); alpha "
        f"{cal.alpha:g}, the probability that a new flight of these conditions breaks the "
        f"premise, {conf}; lambda_hat {cal.lambda_hat:.4g}; flights reached dist "
        f"{cal.tested_range:.4g}; conditions: {cond}"
    ]


def monitor_lines(spec: MonitorSpec) -> list[str]:
    """What the onboard monitor checks (docs/monitor.md)."""
    if not spec.active:
        return ["monitor: off (no guarantee to monitor)"]
    trip = [f"{CHANNELS[i]} {spec.threshold[i]:.6g}" for i, k in enumerate(spec.kind) if k == TRIP]
    count = [
        f"{CHANNELS[i]} {spec.threshold[i]:.6g}" for i, k in enumerate(spec.kind) if k == COUNT
    ]
    off = [CHANNELS[i] for i, k in enumerate(spec.kind) if k == OFF]
    out = ["monitor (docs/monitor.md): a tick trips when the premise is proven broken:"]
    if trip:
        out.append("  |y_i - r_i| beyond " + ", ".join(trip) + " (envelope + error bound)")
    if count:
        out.append(
            f"  more than m = {spec.m} ticks in any {spec.window} with |y_v - v_ref| (gated) "
            "beyond " + ", ".join(count)
        )
    if off:
        out.append(
            "  not checked: " + ", ".join(off) + " (not measured, or the threshold is at or "
            "beyond the gate, so the gated deviation cannot exceed it)"
        )
    out.append(
        "  it cannot see a premise broken without the measurement showing it (an error that "
        "hides the deviation, a bias inside the envelope)"
    )
    return out


def theorem_lines(cdir: ControllerDir, spec: MonitorSpec) -> list[str]:
    """The generalized theorem (docs/guarantee.md) in the certificate's own numbers: the
    premise, the condition and what it guarantees, how far the premise was tested."""
    cert = cdir.certificate
    return [
        *_premise_lines(cdir),
        *_conclusion_lines(cert, spec),
        _tested_range_line(cert),
        *_calibration_lines(cert.calibration),
    ]


def _premise_lines(cdir: ControllerDir) -> list[str]:
    """The norms, what is measured, the premise (i)-(iii) ``e = d + o`` and the start."""
    cert = cdir.certificate
    p = cert.premise
    wx = p.state_scale if p is not None else [1.0] * 6
    we = p.error_scale if p is not None else [1.0] * 6
    beta = p.beta if p is not None else None
    H = cdir.controller.model.H
    h = _diag(np.diag(H)) if np.allclose(H, np.diag(np.diag(H))) else "a full 6x6 matrix"
    full = cert.measure == "full"
    out = [
        f"norms: |z|_x = ||W_x z||_inf, W_x = {_diag(wx)}; |e|_e = ||W_e e||_inf, "
        f"W_e = {_diag(we)}; dist(x) = min over the training states x_d of |x - x_d|_x",
        "measurement: "
        + (
            "full: y = x + e on all six channels"
            if full
            else "position only: y = p + e; the velocity is neither measured nor its error "
            "bounded by this certificate (the vehicle's velocity deviation is bounded, below)"
        ),
        "premise: e_k = d_k + o_k"
        + (
            f", d = clip(e, -beta, beta) on the velocities (beta = {beta:g}), o the rest"
            if beta is not None and full
            else " with o = 0 (no sparse part)"
        ),
    ]
    if cert.m > 0 and beta is not None and full:
        src = "2 V - beta, the gate" if cert.gate is not None else "given"
        out.append(
            f"  (i) at most m = {cert.m} nonzero o_k in any T = {cert.T} consecutive ticks, "
            f"||o_k||_inf <= eps_o = {_g(cert.eps_o)} ({src})"
        )
    else:
        out.append("  (i) no outliers: o_k = 0 at every tick")
    out.append(
        f"  (ii) |d_k|_e <= eps + S dist(x_k) while dist(x_k) <= r: eps = {_g(cert.eps_e)}, "
        f"S = {_g(cert.S)}, r = {_g(cert.radius)}"
    )
    src = (p.eps_w_source if p is not None else None) or "not recorded"
    if src == "input_free_residual":
        src += " (a LOWER bound on any controller's realized w: inputs were not logged)"
    out.append(
        f"  (iii) ||H^-1 w_k||_inf <= eps_w = {_g(cert.eps_w)}, H = {h}, eps_w from: {src}; "
        f"dist(x_ref,k) <= Delta = {_g(cert.delta)}"
    )
    if cert.eps_b > 0:
        out.append(
            f"  (iii') with the bias term: w_k = D_w beta + w'_k, one constant acceleration "
            f"||beta||_inf <= eps_b = {_g(cert.eps_b)} m/s^2 and ||w'_k||_inf <= eps_w; the "
            "taps have integral action (docs/guarantee.md#the-bias-term)"
        )
    out.append(
        "  the flight starts on the reference (||H^-1 (x_0 - r_0)||_inf <= eps_w) with the "
        "controller reset"
    )
    if cert.gate is not None:
        out.append(
            f"gate: _step clips the velocity deviation to +/- V = {cert.gate:g} m/s before the "
            "filter bank (the guarantee needs it)"
        )
    return out


def _conclusion_lines(cert: Certificate, spec: MonitorSpec) -> list[str]:
    """The condition ``(S + eps/r) N + (a + eps_o G_m)/r < 1`` with its numbers, then the
    bounds it gives at every tick (``rho*``, ``gamma``, the monitor's envelope)."""
    p = cert.premise
    beta = p.beta if p is not None else None
    full = cert.measure == "full"
    out = [
        f"condition: (S + eps/r) N + (a + eps_o G_m)/r = {_g(cert.robustness_lhs)} < 1 with "
        f"N = {_g(cert.norm_N)}, N_w = {_g(cert.norm_N_w)}, G_m = {_g(cert.G_m)}, "
        + (
            f"G_b = {_g(cert.G_b)}, a = eps_w N_w + eps_b G_b + Delta = {_g(cert.a)}"
            if cert.eps_b > 0
            else f"a = eps_w N_w + Delta = {_g(cert.a)}"
        )
    ]
    err = f"|d_k|_e <= gamma = eps + S rho* = {_g(cert.gamma)}"
    if full and cert.m > 0 and beta is not None:
        err += ", ||e_k||_inf at most that plus eps_o on the velocity channels"
    elif not full:
        err += " on the positions (the velocity error is not bounded)"
    out.append(f"then at every tick: dist(x_k) <= rho* = {_g(cert.rho_star)} <= r; {err}")
    env = ", ".join(f"{CHANNELS[i]} {spec.envelope[i]:.4g}" for i in range(len(spec.envelope)))
    out.append(f"  and |x_k - r_k| per channel <= {env} (docs/monitor.md)")
    if cert.gate is not None and cert.rho_v is not None:
        out.append(f"  |v_k - v_ref,k| <= rho_v = {_g(cert.rho_v)} <= V = {cert.gate:g}")
    return out


def _tested_range_line(cert: Certificate) -> str:
    """How far from the training states the premise's S was tested (or calibrated)."""
    tr = cert.tested_range
    if tr is None:
        return "tested range: S was not tested on left-out data"
    beyond = (
        f" (rho* = {_g(cert.rho_star)} extrapolates beyond it)"
        if cert.rho_star is not None and cert.rho_star > tr
        else ""
    )
    how = ("the calibration flights reached dist" if cert.calibration is not None
           else "S tested on left-out data out to")  # fmt: skip
    return f"tested range: {how} {_g(tr)}{beyond}"


def verification_lines(cdir: ControllerDir) -> list[str]:
    """Whether the certificate was verified (docs/verify.md), deterministically (no date): its
    numbers were recomputed from the taps on load (a mismatch is refused before export), and
    how many of the tick logs its calibration record lists lie beside it (in the calibration
    output two folders up) with the sha256 it states. Scores are recomputed by ``qsls verify``,
    not here."""
    from qsls.pipeline.core.artifacts import sha256_file  # deferred: only an export hashes

    out = ["verification: certificate numbers recomputed from the taps: match"]
    cal = cdir.certificate.calibration
    if cal is None:
        return out
    if not cal.evidence:
        return [*out, "evidence: the calibration record lists no tick logs (not verifiable)"]
    root = cdir.folder.parent.parent
    found = 0
    for e in cal.evidence:
        f = Path(e.ticks) if Path(e.ticks).is_absolute() else root / e.ticks
        found += bool(f.is_file() and sha256_file(f) == e.sha256)
    n = len(cal.evidence)
    state = "verified" if found == n else "NOT verified"
    return [
        *out,
        f"evidence {state}: {found} of {n} tick logs the calibration lists were found with their "
        "sha256 (qsls verify recomputes the scores, lambda_hat and the tested range from them)",
    ]


def statement(cdir: ControllerDir, spec: MonitorSpec, reason: str) -> list[str]:
    """Every line a generated file states about the guarantee, the first naming the status,
    the second whether it was verified (:func:`verification_lines`)."""
    cert = cdir.certificate
    lines = [first_line(cert, reason), *verification_lines(cdir)]
    if cert.status in (CERTIFIED, RELAXED) and cert.robust and cert.rho_star is not None:
        if not has_guarantee(cert):
            lines.append("the numbers it was synthesized against (NOT a guarantee):")
        lines += theorem_lines(cdir, spec)
    else:
        lines.append(f"no theorem: status {cert.status} ({reason})")
    lines += monitor_lines(spec)
    lines += innovation_lines(innovation_of(cdir))
    return lines


def innovation_lines(inn: InnovationSpec) -> list[str]:
    """What the innovation monitor checks and in which mode (docs/monitor.md)."""
    if not inn.active:
        return []
    out = [
        f"innovation monitor: window sums of nu over {', '.join(str(k) for k in inn.windows)} "
        f"ticks on {', '.join(CHANNELS[c] for c in inn.live_channels()) or 'no channel'}"
    ]
    if inn.mode == "calibrated":
        out.append(
            f"  calibrated: thresholds {inn.scale:.4g} of the sound ones (the conformal quantile "
            f"of the calibration flights' statistics); a next flight of its conditions trips "
            f"them with probability at most {inn.false_trip_rate:g} (a trip is not a proof)"
        )
    else:
        out.append("  sound: a trip proves the premise broken on this flight")
    return out
