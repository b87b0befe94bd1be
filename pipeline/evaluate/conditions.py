"""The conditions a certificate is calibrated under, as a stated family, and the check of a
flight's conditions against it (docs/calibration.md, Conditions as a stated family).

A calibrated promise holds for a new flight *exchangeable* with the calibration flights, so
it holds only under the conditions they were drawn from. The calibration draws each
calibration, range and validation flight's conditions from :class:`ConditionFamily` (by
the flight's seed), records per flight what was drawn, and the certificate states:

- ``family``: the ranges drawn from (the vehicle's true mass, the reference's radius,
  period, height and centre; where the family ranges them, the steady wind's speed and
  direction, the gust's amplitude, the rotors' thrust constant and the battery's sag);
- ``vehicle``, ``reference``, ``vio``, ``wind``: every other condition, fixed at its recorded
  value (the vehicle and its integrator, the reference's kind and timing, every parameter of
  the VIO emulator, the wind where there was one); ``perception``, ``estimator`` and
  ``duration_s`` as before. A certificate that states no wind, thrust constant or sag was
  calibrated in still air, at the nominal thrust constant, without sag (they did not exist
  before), and a flight is compared with those.

:func:`outside_family` compares *all* of a flight's recorded conditions with that statement
and says which condition lies outside and by how much; a flight outside is outside the
certificate, whatever its verdict.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from pydantic import Field, model_validator

from qsls.pipeline.core.config import Options
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.sim.options import Px4Options, VioParams, WindOptions

FAMILY_STREAM = 0x46414D
"""The random stream of the family's draws (``SeedSequence([seed, FAMILY_STREAM])``): apart
from every stream of the flight itself, so a point family changes no flight."""

Span = tuple[float, float]

REL_TOL = 1e-9
"""Two recorded numbers are one condition within this relative tolerance (a round trip
through JSON and YAML is exact; this absorbs nothing a user could set)."""

UNCOMPARED = {"reference": {"laps"}, "vio": {"perception"}}
"""Recorded but compared elsewhere: the laps only set a flight's natural length (the flight
length is compared as ``duration_s``), the perception condition is its own key."""


class ConditionFamily(Options):
    """The family the calibration draws each flight's conditions from (``calibrate.family``);
    every range ``[low, high]`` is drawn uniformly, a point range keeps the condition fixed.
    The controller keeps the mass it was synthesized for: a drawn mass is the vehicle's true
    one (a heavier battery), which the controller does not know."""

    mass: Span = (1.0, 1.0)
    """The vehicle's true mass relative to ``vehicle.mass`` (``[0.97, 1.03]``: +-3 %)."""
    radius: Span | None = None
    """The reference's radius (m); None: fixed at ``reference.radius``."""
    period: Span | None = None
    """The reference's period (s); None: fixed."""
    height: Span | None = None
    """The reference's height (m); None: fixed."""
    center_offset: float = Field(0.0, ge=0.0, le=10.0)
    """The reference's centre moved up to this far (m, uniform in the disc)."""
    start_offset: float = Field(0.0, ge=0.0, le=10.0)
    """The vehicle starts up to this far beside the reference's first point (m, uniform in the
    horizontal disc) and flies to the reference from there; 0: on it."""
    figure8: float = Field(0.0, ge=0.0, le=1.0)
    """The share of flights that fly the figure-eight instead of the recorded reference's kind
    (drawn per flight, with the same radius, period, height and centre draws); 0: the kind is
    fixed."""
    wind: Span | None = None
    """The steady horizontal wind's speed (m/s, ``[0, 1.5]``: light wind); None: fixed at
    ``wind.speed`` (still air unless set)."""
    wind_direction: Span | None = None
    """Where the wind blows to (degrees from +x); None: uniform over the circle where
    ``wind`` is drawn, else fixed at ``wind.direction_deg``."""
    gust: Span | None = None
    """The gust's amplitude (m/s, along the wind); None: fixed at ``wind.gust``."""
    thrust_constant: Span | None = None
    """The rotors' thrust constant relative to nominal (``[0.95, 1.05]``: +-5 %), which the
    controller is not told; None: fixed at ``vehicle.thrust_constant``."""
    sag: Span | None = None
    """The battery's sag, the share of thrust lost by the flight's end (``[0, 0.05]``);
    None: fixed at ``vehicle.sag``."""
    estimator: dict[str, Span] = Field(default_factory=dict)
    """The VIO emulator's numeric parameters drawn per flight, by their path in ``vio``
    (``{noise_velocity: [0.012, 0.018], regular.light: [0.9, 1.0]}``): each uniform in its
    range; the others fixed at their recorded values."""
    hover_error: Span | None = None
    """The relative error of the hover throttle PX4's interface assumes (its hover-thrust
    estimate, converged: ``[-0.02, 0.02]``), drawn as ``px4.hover_estimate = hover_thrust
    (1 + e)``; needs ``px4.interface: px4``. None: fixed at the options' estimate."""

    @model_validator(mode="after")
    def _ranges(self) -> ConditionFamily:
        base = VioParams().model_dump(mode="json")
        for path, (lo, hi) in self.estimator.items():
            have = _at(base, path)
            if isinstance(have, bool) or not isinstance(have, int | float):
                raise ValueError(
                    f"family.estimator.{path}: not a numeric parameter of the VIO emulator "
                    "(a path in sim.vio such as noise_velocity or regular.light)"
                )
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo <= hi):
                raise ValueError(f"family.estimator.{path} [{lo}, {hi}]: need 0 <= low <= high")
        for name in ("mass", "radius", "period", "height"):
            span = getattr(self, name)
            if span is None:
                continue
            lo, hi = span
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
                raise ValueError(f"family.{name} [{lo}, {hi}]: need 0 < low <= high, finite")
        if not self.mass[1] <= 2.0:
            raise ValueError(f"family.mass up to {self.mass[1]}: at most twice the mass")
        for name, (least, most) in NEW_LIMITS.items():
            span = getattr(self, name)
            if span is None:
                continue
            lo, hi = span
            if not (math.isfinite(lo) and math.isfinite(hi) and least <= lo <= hi <= most):
                raise ValueError(
                    f"family.{name} [{lo}, {hi}]: need {least:g} <= low <= high <= {most:g}"
                )
        return self

    @property
    def point(self) -> bool:
        """Every condition fixed at the simulation options' own: the calibration flies one
        vehicle on one reference (a degenerate range such as ``radius: [1.2, 1.2]`` sets its
        condition for every flight, so it is not a point family)."""
        spans = [self.radius, self.period, self.height, *(getattr(self, n) for n in NEW_LIMITS)]
        fixed = (
            self.center_offset == 0 and self.mass == (1.0, 1.0) and not self.estimator
            and self.figure8 == 0 and self.start_offset == 0
        )  # fmt: skip
        return fixed and all(s is None for s in spans)

    @property
    def ranges_new(self) -> bool:
        """Whether the family draws the wind, the thrust constant or the sag."""
        return any(getattr(self, n) is not None for n in NEW_LIMITS)


NEW_LIMITS: dict[str, tuple[float, float]] = {
    "wind": (0.0, 20.0),
    "wind_direction": (-360.0, 360.0),
    "gust": (0.0, 10.0),
    "thrust_constant": (0.5, 1.5),
    "sag": (0.0, 0.5),
    "hover_error": (-0.5, 0.5),
}
"""The family's ranges of the conditions added by issue 47 (item 2), within the simulator's
own limits (:class:`qsls.pipeline.sim.options.WindOptions`, ``VehicleOptions``)."""


def _lerp(span: Span, u: float) -> float:
    return float(span[0] + (span[1] - span[0]) * u)


def draw(family: ConditionFamily, seed: int, sim: Mapping[str, Any]) -> dict[str, Any]:
    """The overrides of flight ``seed``'s simulation options drawn from ``family`` (empty for
    a point family, so its flights are byte-identical to the fixed ones). ``sim`` is the
    base options' dump; the mass drawn is the vehicle's, the controller keeps the base's."""
    if family.point:
        return {}
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), FAMILY_STREAM]))
    u = rng.uniform(size=6)
    v = rng.uniform(size=5)  # after the first six: a family without them draws as before
    veh, ref = dict(sim.get("vehicle") or {}), dict(sim.get("reference") or {})
    out: dict[str, Any] = {}
    m0 = float(veh.get("mass", 0.256))
    lo, hi = family.mass
    if lo != hi or lo != 1.0:
        out["vehicle"] = {"mass": m0 * (lo + (hi - lo) * u[0])}
        out["px4"] = {"controller_mass": m0}
    r: dict[str, Any] = {}
    for i, name in enumerate(("radius", "period", "height"), start=1):
        span = getattr(family, name)
        if span is not None:
            r[name] = span[0] + (span[1] - span[0]) * u[i]
    if family.center_offset > 0:
        cx, cy = ref.get("center", (0.0, 0.0))
        rad, ang = family.center_offset * math.sqrt(u[4]), 2 * math.pi * u[5]
        r["center"] = [float(cx) + rad * math.cos(ang), float(cy) + rad * math.sin(ang)]
    if family.figure8 > 0:  # a stream of its own: the draws above stay as they were
        kind = np.random.default_rng(np.random.SeedSequence([int(seed), FAMILY_STREAM, 3]))
        if float(kind.uniform()) < family.figure8:
            r["kind"] = "figure8"
    if r:
        out["reference"] = r
    if family.start_offset > 0:  # a stream of its own, as the figure-eight's
        st = np.random.default_rng(np.random.SeedSequence([int(seed), FAMILY_STREAM, 4]))
        rad, ang = family.start_offset * math.sqrt(st.uniform()), 2 * math.pi * st.uniform()
        out["start_offset"] = [rad * math.cos(ang), rad * math.sin(ang)]
    for i, name in ((3, "thrust_constant"), (4, "sag")):
        span = getattr(family, name)
        if span is not None:
            out.setdefault("vehicle", {})[name] = _lerp(span, v[i])
    w: dict[str, float] = {}
    if family.wind is not None:
        w["speed"] = _lerp(family.wind, v[0])
        w["direction_deg"] = _lerp(family.wind_direction or (0.0, 360.0), v[1])
    elif family.wind_direction is not None:
        w["direction_deg"] = _lerp(family.wind_direction, v[1])
    if family.gust is not None:
        w["gust"] = _lerp(family.gust, v[2])
    if w:
        out["wind"] = w
    if family.hover_error is not None:
        px4 = Px4Options.model_validate(sim.get("px4") or {})
        if px4.interface != "px4":
            raise ConfigError(
                "calibrate.family.hover_error draws the hover-thrust estimate of PX4's "
                "interface: set sim px4.interface: px4 (or drop hover_error)"
            )
        e = _lerp(family.hover_error, float(rng.uniform()))  # after v: earlier draws unchanged
        out.setdefault("px4", {})["hover_estimate"] = px4.hover_thrust * (1.0 + e)
    if family.estimator:  # a stream of its own: the draws above stay as they were
        est = np.random.default_rng(np.random.SeedSequence([int(seed), FAMILY_STREAM, 2]))
        vio: dict[str, Any] = {}
        for path in sorted(family.estimator):
            _put(vio, path, _lerp(family.estimator[path], float(est.uniform())))
        out["vio"] = vio
    return out


def _at(tree: Mapping[str, Any], path: str) -> Any:
    """The value at the dotted ``path`` of a nested mapping (None where there is none)."""
    node: Any = tree
    for key in path.split("."):
        if not isinstance(node, Mapping) or key not in node:
            return None
        node = node[key]
    return node


def _put(tree: dict[str, Any], path: str, value: float) -> None:
    *head, last = path.split(".")
    for key in head:
        tree = tree.setdefault(key, {})
    tree[last] = value


def drawn(family: ConditionFamily, sim: Mapping[str, Any]) -> dict[str, float]:
    """What a flight of options ``sim`` met of a non-point ``family`` (the scores' columns:
    ``mass_kg``, ``radius_m``, ``period_s``, ``height_m``, ``center_x_m``, ``center_y_m``,
    and where the family draws any of them ``wind_mps``, ``wind_dir_deg``, ``gust_mps``,
    ``thrust_constant``, ``sag``); empty for a point family (the scores stay as they were)."""
    if family.point:
        return {}
    veh, ref = sim.get("vehicle") or {}, sim.get("reference") or {}
    cx, cy = ref.get("center", (0.0, 0.0))
    out = {"mass_kg": float(veh["mass"]), "radius_m": float(ref["radius"]),
           "period_s": float(ref["period"]), "height_m": float(ref["height"]),
           "center_x_m": float(cx), "center_y_m": float(cy)}  # fmt: skip
    if family.ranges_new:
        wind = WindOptions.model_validate(sim.get("wind") or {})
        out |= {"wind_mps": wind.speed, "wind_dir_deg": wind.direction_deg,
                "gust_mps": wind.gust, "thrust_constant": float(veh.get("thrust_constant", 1.0)),
                "sag": float(veh.get("sag", 0.0))}  # fmt: skip
    if family.hover_error is not None:
        out["hover_error"] = hover_error(sim.get("px4"))
    if family.figure8 > 0:
        out["figure8"] = float(ref.get("kind") == "figure8")
    if family.start_offset > 0:
        sx, sy = sim.get("start_offset") or (0.0, 0.0)
        out |= {"start_x_m": float(sx), "start_y_m": float(sy)}
    for path in sorted(family.estimator):
        out[f"vio_{path.replace('.', '_')}"] = float(_at(sim.get("vio") or {}, path))
    return out


def hover_error(px4: Mapping[str, Any] | None) -> float:
    """The relative error of the hover throttle the interface assumes, ``hover_estimate /
    hover_thrust - 1`` (0 without PX4's interface, or with the estimate at the truth)."""
    opts = Px4Options.model_validate(px4 or {})
    return float(opts.estimate / opts.hover_thrust - 1.0)


def stated(family: ConditionFamily, sim: Mapping[str, Any]) -> dict[str, Any]:
    """What a certificate states of its conditions beyond perception, estimator and length:
    the family's ranges in absolute units and every other condition at its recorded value."""
    veh, ref = dict(sim.get("vehicle") or {}), dict(sim.get("reference") or {})
    m0 = float(veh.get("mass", 0.256))
    fam: dict[str, Any] = {"mass": [m0 * family.mass[0], m0 * family.mass[1]]}
    for name in ("radius", "period", "height"):
        span = getattr(family, name)
        fam[name] = list(span) if span is not None else [float(ref[name])] * 2
    fam["center"] = list(ref.get("center", (0.0, 0.0)))
    fam["center_offset"] = family.center_offset
    for name in NEW_LIMITS:  # stated where ranged: an older statement stays as it was
        span = getattr(family, name)
        if name == "wind_direction" and span is None and family.wind is not None:
            span = (0.0, 360.0)  # drawn uniformly over the circle
        if span is not None:
            fam[name] = list(span)
    if family.estimator:
        fam["estimator"] = {k: list(v) for k, v in sorted(family.estimator.items())}
    if family.figure8 > 0:  # stated where drawn: an older statement stays as it was
        fam["figure8"] = family.figure8
    if family.start_offset > 0:
        fam["start_offset"] = family.start_offset
    out = {"family": fam, "vehicle": veh, "reference": ref, "vio": dict(sim.get("vio") or {})}
    if sim.get("wind"):
        out["wind"] = dict(sim["wind"])
    if sim.get("px4"):
        out["px4"] = dict(sim["px4"])
    return out


def flight_conditions(sim: Mapping[str, Any]) -> dict[str, Any]:
    """A flight's recorded conditions from its simulation options' dump: the vehicle (its
    true mass, thrust constant and sag), the reference, the VIO emulator's parameters and
    the wind, the interface and the start beside the reference (where not the default)."""
    out: dict[str, Any] = {k: dict(sim.get(k) or {}) for k in ("vehicle", "reference", "vio")}
    for k in ("wind", "px4"):
        if sim.get(k):
            out[k] = dict(sim[k])
    if sim.get("start_offset"):
        out["start_offset"] = [float(c) for c in sim["start_offset"]]
    return out


def _differs(a: Any, b: Any) -> bool:
    if isinstance(a, bool | str) or isinstance(b, bool | str) or a is None or b is None:
        return bool(a != b)
    if isinstance(a, int | float) and isinstance(b, int | float):
        return not math.isclose(float(a), float(b), rel_tol=REL_TOL, abs_tol=1e-12)
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) != len(b) or any(_differs(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        return set(a) != set(b) or any(_differs(a[k], b[k]) for k in a)
    return bool(a != b)


def _span(name: str, value: float, span: list[float], unit: str) -> str:
    lo, hi = float(span[0]), float(span[1])
    if lo - REL_TOL * abs(lo) <= value <= hi + REL_TOL * abs(hi):
        return ""
    edge = hi if value > hi else lo
    rel = f" ({100 * (value - edge) / abs(edge):+.1f} % beyond)" if edge else ""
    fixed = f"{lo:.4g}" if lo == hi else f"[{lo:.4g}, {hi:.4g}]"
    return f"{name} {value:.4g}{unit}, calibrated at {fixed}{unit}{rel}"


def outside_conditions(
    perception: str,
    flight_s: float,
    calibrated_perception: str,
    calibrated_s: float,
    estimator: str = "",
    calibrated_estimator: str = "",
) -> str:
    """Why a flight lies outside the conditions its certificate was calibrated under ('' when
    inside): another perception condition, another estimator (the camera loop against the VIO
    emulator: each errs its own way; ``''`` where not known), or a flight longer than the
    calibration flights (the promise ``P(lambda_hat)`` is about a new flight *of the same
    conditions*, and the premise's quantities grow with a flight's length:
    docs/calibration.md)."""
    why = []
    if calibrated_perception and perception != calibrated_perception:
        why.append(f"perception {perception}, calibrated in {calibrated_perception}")
    if estimator and calibrated_estimator and estimator != calibrated_estimator:
        why.append(f"estimator {estimator}, calibrated with {calibrated_estimator}")
    if flight_s > calibrated_s + 1e-6:
        why.append(f"a {flight_s:g} s flight, calibrated on {calibrated_s:g} s flights")
    return "; ".join(why)


def outside_family(statement: Mapping[str, Any], flight: Mapping[str, Any]) -> list[str]:
    """Each of ``flight``'s conditions (:func:`flight_conditions`) that lies outside what the
    certificate states (:func:`stated`), in words with how far; empty when every one lies
    inside. A condition the statement does not record is not compared (an older record); a
    recorded flights' certificate states its logs' conditions, compared where they are read
    (:mod:`qsls.pipeline.calibrate.flights`)."""
    if statement.get("source") in ("recorded", "standin"):
        # a log's conditions are stated as its log says them (calibrate/stage._recorded_phases)
        return []
    fam = statement.get("family")
    why: list[str] = []
    ranged: dict[str, set[str]] = {"vehicle": set(), "reference": set()}
    if fam:
        veh, ref = flight.get("vehicle") or {}, flight.get("reference") or {}
        checks = [("mass", veh.get("mass"), fam.get("mass"), " kg", "vehicle")]
        checks += [(n, ref.get(n), fam.get(n), u, "reference")
                   for n, u in (("radius", " m"), ("period", " s"), ("height", " m"))]  # fmt: skip
        for name, value, span, unit, group in checks:
            if value is None or span is None:
                continue
            ranged[group].add(name)
            if text := _span(name, float(value), span, unit):
                why.append(text)
        if fam.get("figure8"):  # the recorded kind or the figure-eight
            ranged["reference"].add("kind")
            base = (statement.get("reference") or {}).get("kind", "circle")
            if ref.get("kind", "circle") not in (base, "figure8"):
                why.append(f"reference {ref.get('kind')!r}, calibrated on {base!r} and 'figure8'")
        if "center" in ref and fam.get("center") is not None:
            ranged["reference"].add("center")
            d = math.dist([float(c) for c in ref["center"]], [float(c) for c in fam["center"]])
            if d > float(fam.get("center_offset", 0.0)) + 1e-9:
                why.append(f"reference centre {d:.3g} m from the calibrated centre "
                           f"(up to {float(fam.get('center_offset', 0.0)):.3g} m)")  # fmt: skip
    start = math.hypot(*(flight.get("start_offset") or (0.0, 0.0)))
    allowed = float((fam or {}).get("start_offset", 0.0))
    if start > allowed + 1e-9:
        why.append(f"start {start:.3g} m beside the reference's first point, calibrated "
                   f"at up to {allowed:.3g} m")  # fmt: skip
    why += _unseen_forces(statement, flight)
    why += _interface(statement, flight)
    estimator = (fam or {}).get("estimator") or {}
    for path, span in sorted(estimator.items()):
        value = _at(flight.get("vio") or {}, path)
        if value is not None and (text := _span(f"vio.{path}", float(value), span, "")):
            why.append(text)
    ranged["vehicle"] |= {"thrust_constant", "sag"}
    for group in ("vehicle", "reference", "vio"):
        have, want = flight.get(group) or {}, statement.get(group)
        if not want:
            continue
        skip = ranged.get(group, set()) | UNCOMPARED.get(group, set())
        if group == "vio":  # the drawn parameters were compared with their ranges above
            have, want = _without(have, estimator), _without(want, estimator)
        for key in sorted(set(want) | set(have)):
            if key in skip:
                continue
            if key not in have or key not in want or _differs(have[key], want[key]):
                why.append(f"{group}.{key} {have.get(key)!r}, calibrated at {want.get(key)!r}")
    return why


def _fixed(value: float) -> list[float]:
    return [value, value]


def _unseen_forces(statement: Mapping[str, Any], flight: Mapping[str, Any]) -> list[str]:
    """The wind, the gust, the thrust constant and the sag of ``flight`` against the
    statement's family where it ranges them, else against its recorded value, else (an
    older record: they did not exist) still air, the nominal thrust constant and no sag."""
    fam = statement.get("family") or {}
    sveh, fveh = statement.get("vehicle") or {}, flight.get("vehicle") or {}
    swind = WindOptions.model_validate(statement.get("wind") or {})
    fwind = WindOptions.model_validate(flight.get("wind") or {})
    why: list[str] = []
    checks = [
        ("wind", fwind.speed, fam.get("wind") or _fixed(swind.speed), " m/s"),
        ("gust", fwind.gust, fam.get("gust") or _fixed(swind.gust), " m/s"),
        ("thrust constant", float(fveh.get("thrust_constant", 1.0)),
         fam.get("thrust_constant") or _fixed(float(sveh.get("thrust_constant", 1.0))), ""),
        ("sag", float(fveh.get("sag", 0.0)), fam.get("sag") or _fixed(float(sveh.get("sag", 0.0))), ""),
    ]  # fmt: skip
    for name, value, span, unit in checks:
        if text := _span(name, value, span, unit):
            why.append(text)
    if fwind.off:
        return why
    calm = max(float((fam.get("wind") or _fixed(swind.speed))[1]),
               float((fam.get("gust") or _fixed(swind.gust))[1])) == 0  # fmt: skip
    if not calm:  # a wind the calibration flew: from where it blew
        lo, hi = (float(a) for a in fam.get("wind_direction") or _fixed(swind.direction_deg))
        if hi - lo < 360.0:
            off = (fwind.direction_deg - lo) % 360.0  # degrees past the range's start
            if off > hi - lo + 1e-9:
                beyond = min(off - (hi - lo), 360.0 - off)
                fixed = f"{lo:.4g}" if lo == hi else f"[{lo:.4g}, {hi:.4g}]"
                why.append(f"wind direction {fwind.direction_deg:.4g} deg, calibrated at "
                           f"{fixed} deg ({beyond:.3g} deg beyond)")  # fmt: skip
    if fwind.gust > 0 and _differs(fwind.gust_hz, swind.gust_hz):
        why.append(f"wind.gust_hz {fwind.gust_hz:g}, calibrated at {swind.gust_hz:g}")
    return why


PX4_RANGED = {"hover_estimate", "controller_mass"}
"""The interface's keys compared elsewhere: the estimate as its error against the family's
range, the controller's mass as the vehicle's design mass (the family draws the true one)."""


def _interface(statement: Mapping[str, Any], flight: Mapping[str, Any]) -> list[str]:
    """The interface the flight was flown through against the calibration's: PX4's or the
    paper's, the hover-thrust estimate's error against the family's range (else its recorded
    value), and every other PX4 stand-in option exactly."""
    sp, fp = statement.get("px4") or {}, flight.get("px4") or {}
    s_opts, f_opts = Px4Options.model_validate(sp), Px4Options.model_validate(fp)
    if s_opts.interface != f_opts.interface:
        return [f"interface {f_opts.interface!r}, calibrated through {s_opts.interface!r}"]
    fam = statement.get("family") or {}
    span = fam.get("hover_error") or _fixed(hover_error(sp))
    why = [t for t in [_span("hover-thrust estimate error", hover_error(fp), span, "")] if t]
    for key in sorted((set(sp) | set(fp)) - PX4_RANGED):
        if _differs(getattr(f_opts, key), getattr(s_opts, key)):
            why.append(
                f"px4.{key} {getattr(f_opts, key)!r}, calibrated at {getattr(s_opts, key)!r}"
            )
    return why


def _without(tree: Mapping[str, Any], paths: Mapping[str, Any]) -> dict[str, Any]:
    """``tree`` without the leaves at ``paths`` (dotted), as a new nested dict."""
    out = copy.deepcopy(dict(tree))
    for path in paths:
        *head, last = path.split(".")
        node: Any = out
        for key in head:
            node = node.get(key) if isinstance(node, dict) else None
        if isinstance(node, dict):
            node.pop(last, None)
    return out
