"""Reference trajectories: the paper's circle at constant height, hover, a figure-eight.

Every flight starts like a real one: ``hold_s`` seconds at rest at ``takeoff_height`` above
the pattern's centre, a climb of ``takeoff_s`` seconds to ``height``, then a straight flight
of ``approach_s`` seconds from the centre to the pattern's first point (each move a quintic
smoothstep ``s5(u) = 10 u^3 - 15 u^4 + 6 u^5``, at rest at both ends). Besides being what
real logs show, the take-off and the approach pin the clock offset and the frame yaw that
``ingest`` recovers: on a circle alone they are not separable (shifting a circle in time is
rotating it about its centre). The 3 s hold keeps the climb clear of the first seconds
that an offset search drops (``ingest`` uses only VIO samples that stay inside the truth's
time range for every candidate offset, up to 2 s).

Then the pattern starts at rest and speeds up smoothly (``t`` counted from its start): the
phase is
``theta(t) = omega T_r S(t / T_r)`` for ``t < T_r`` with ``S(u) = 2.5 u^4 - 3 u^5 + u^6`` (the
integral of the quintic smoothstep, so the angular rate ``omega s(t/T_r)`` and its derivative
are continuous), then ``theta(t) = omega (t - T_r / 2)``; ``omega = 2 pi / period``.

- circle: ``p = c + radius (cos theta, sin theta, 0) + (0, 0, height)`` (starts at ``+x``).
- figure8 (lemniscate of Gerono): ``p = c + radius (sin theta, sin(2 theta) / 2, 0) + height``.
- hover: ``p = c + (0, 0, height)``.

:meth:`Reference.sample` returns position, velocity, acceleration (for feedforward) and the
reference state ``r = [p, v]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, get_args

import numpy as np
from pydantic import Field

from qsls.pipeline.core.config import Options, validate
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.core.plant import Plant, model_feedforward


class ReferenceOptions(Options):
    """The trajectory to fly (the paper's experiment: a circle at constant height)."""

    kind: Literal["circle", "hover", "figure8"] = "circle"
    radius: float = Field(1.0, gt=0)
    """Circle radius / figure-eight half-width (m)."""
    period: float = Field(5.0, gt=0)
    """Seconds per lap (0.2 Hz by default)."""
    height: float = Field(1.0, gt=0)
    """Flight height above the floor (m)."""
    center: tuple[float, float] = (0.0, 0.0)
    """Horizontal centre (m)."""
    laps: float = Field(3.0, gt=0)
    """Laps to fly when the duration is not given (the paper's simulation flew three)."""
    ramp_s: float = Field(2.0, ge=0)
    """Smooth speed-up from rest (s)."""
    takeoff_height: float = Field(0.3, gt=0)
    """Height at which the flight (and the log) starts (m)."""
    hold_s: float = Field(3.0, ge=0)
    """Seconds at rest at the take-off height before climbing (3 s: see the module doc)."""
    takeoff_s: float = Field(2.0, ge=0)
    """Duration of the climb to ``height`` (s); 0 starts at ``height``."""
    approach_s: float = Field(2.0, ge=0)
    """Duration of the straight flight from the centre to the pattern's first point (s)."""

    @property
    def start_s(self) -> float:
        """When the pattern starts (after hold, climb and approach)."""
        return self.hold_s + self.takeoff_s + self.approach_s

    def natural_duration(self) -> float:
        """Take-off, then ``ramp_s / 2 + laps * period`` (hover: ``laps * period``)."""
        extra = 0.5 * self.ramp_s if self.kind != "hover" else 0.0
        return self.start_s + extra + self.laps * self.period


def parse_reference(spec: str, what: str = "reference") -> ReferenceOptions:
    """The one text form of a reference: ``KIND`` or ``KIND:key=value,key=value`` with any
    :class:`ReferenceOptions` field, values as YAML (``center=[0.5,0]``); the centre may also
    be written ``center=0.5;0`` or ``center=0.5 0``. Errors name ``what`` (e.g. ``--reference``)."""
    import yaml

    kind, _, rest = spec.partition(":")
    kinds = get_args(ReferenceOptions.model_fields["kind"].annotation)
    if kind.strip() not in kinds:
        raise ConfigError(
            f"{what} '{spec}': unknown kind '{kind.strip()}' (kinds: {', '.join(kinds)}; "
            "e.g. 'circle:radius=1,height=1,period=5')"
        )
    data: dict[str, Any] = {"kind": kind.strip()}
    depth, start, parts = 0, 0, []
    for i, ch in enumerate(rest + ","):  # commas inside [..] belong to a list value
        depth += (ch in "[(") - (ch in "])")
        if ch == "," and depth == 0:
            parts.append(rest[start:i])
            start = i + 1
    for part in filter(str.strip, parts):
        key, eq, value = part.partition("=")
        if not eq:
            raise ConfigError(f"{what} '{spec}': expected key=value, got '{part.strip()}'")
        key, value = key.strip(), value.strip()
        if key == "center" and not value.startswith("["):
            value = "[" + ",".join(value.replace(";", " ").split()) + "]"
        try:
            data[key] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise ConfigError(f"{what} '{spec}': cannot read the value of '{key}'") from None
    return validate(ReferenceOptions, data, f"{what} '{spec}'")


@dataclass(frozen=True)
class RefSample:
    """Reference at one time: position, velocity, acceleration (world, z up)."""

    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    uff: np.ndarray | None = None
    """The model's feedforward for the tick that starts here (:meth:`Reference.feedforward`),
    where the flight computed it; else the acceleration at this instant stands for it."""

    @property
    def state(self) -> np.ndarray:
        """``r = [p, v]`` (6,)."""
        return np.concatenate([self.p, self.v])


def _move(
    p: np.ndarray, v: np.ndarray, a: np.ndarray, t: np.ndarray, dur: float, d: np.ndarray
) -> None:
    """Add a rest-to-rest move by ``d`` over ``dur`` seconds starting at ``t = 0`` (in place)."""
    if dur <= 0:
        p += d  # instantaneous: already there
        return
    u = np.clip(t / dur, 0.0, 1.0)
    s5 = 10 * u**3 - 15 * u**4 + 6 * u**5
    inside = (t > 0) & (t < dur)
    s5d = np.where(inside, (30 * u**2 - 60 * u**3 + 30 * u**4) / dur, 0.0)
    s5dd = np.where(inside, (60 * u - 180 * u**2 + 120 * u**3) / dur**2, 0.0)
    p += s5[:, None] * d
    v += s5d[:, None] * d
    a += s5dd[:, None] * d


class Reference:
    """A reference trajectory built from :class:`ReferenceOptions`."""

    def __init__(self, options: ReferenceOptions | None = None) -> None:
        self.options = options or ReferenceOptions()
        o = self.options
        self.omega = 2.0 * np.pi / o.period
        self.origin = np.array([o.center[0], o.center[1], o.height], dtype=float)

    def phase(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``theta, theta', theta''`` at times ``t`` (s)."""
        t = np.asarray(t, dtype=float)
        w, tr = self.omega, self.options.ramp_s
        if tr <= 0:
            return w * t, np.full_like(t, w), np.zeros_like(t)
        u = np.clip(t / tr, 0.0, 1.0)
        ramp = t < tr
        th = np.where(ramp, w * tr * (2.5 * u**4 - 3 * u**5 + u**6), w * (t - 0.5 * tr))
        thd = np.where(ramp, w * (10 * u**3 - 15 * u**4 + 6 * u**5), w)
        thdd = np.where(ramp, (w / tr) * (30 * u**2 - 60 * u**3 + 30 * u**4), 0.0)
        return th, thd, thdd

    def arrays(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration (n, 3) at times ``t`` (n,)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        o = self.options
        p, v, a = self._pattern(t - o.start_s)
        early = t < o.start_s
        if not early.any():
            return p, v, a
        te = t[early]
        first, _, _ = self._pattern(np.zeros(1))
        pe = np.tile(self.origin, (len(te), 1))
        pe[:, 2] = o.takeoff_height
        ve = np.zeros_like(pe)
        ae = np.zeros_like(pe)
        # climb: z from takeoff_height to height
        _move(pe, ve, ae, te - o.hold_s, o.takeoff_s, np.array([0, 0, o.height - o.takeoff_height]))
        # approach: centre to the pattern's first point
        d = first[0] - self.origin
        _move(pe, ve, ae, te - o.hold_s - o.takeoff_s, o.approach_s, d)
        p[early], v[early], a[early] = pe, ve, ae
        return p, v, a

    def _pattern(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The pattern at its own time ``t`` (at rest at its start for ``t <= 0``)."""
        t = np.maximum(t, 0.0)
        n = t.shape[0]
        p = np.tile(self.origin, (n, 1))
        v = np.zeros((n, 3))
        a = np.zeros((n, 3))
        kind, rad = self.options.kind, self.options.radius
        if kind == "hover":
            return p, v, a
        th, thd, thdd = self.phase(t)
        if kind == "circle":
            # f = (cos, sin): f' = (-sin, cos), f'' = -(cos, sin)
            f = np.c_[np.cos(th), np.sin(th)]
            f1 = np.c_[-np.sin(th), np.cos(th)]
            f2 = -f
        else:  # figure8: f = (sin th, sin 2th / 2)
            f = np.c_[np.sin(th), 0.5 * np.sin(2 * th)]
            f1 = np.c_[np.cos(th), np.cos(2 * th)]
            f2 = np.c_[-np.sin(th), -2.0 * np.sin(2 * th)]
        p[:, :2] += rad * f
        v[:, :2] = rad * f1 * thd[:, None]
        a[:, :2] = rad * (f2 * thd[:, None] ** 2 + f1 * thdd[:, None])
        return p, v, a

    def feedforward(
        self, t: np.ndarray, dt: float, mass: float, plant: Plant = "hover"
    ) -> np.ndarray:
        """``uff_k`` at the ticks ``t`` (n,) for a controller of step ``dt`` on ``plant``: the
        step mean of the plant's inverse, so that the reference nearly satisfies the model,
        ``r_{k+1} ~ A r_k + B uff_k`` (:func:`qsls.pipeline.core.plant.model_feedforward`;
        docs/guarantee.md, Disturbance in deviation coordinates). The jerk is the acceleration's
        central difference over ``h = 1e-4`` s (the acceleration is analytic; at a move's ends,
        where the jerk jumps, the difference takes the mean of both sides)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        h = 1e-4
        _, v0, a0 = self.arrays(t)
        _, v1, a1 = self.arrays(t + dt)

        def jerk(s: np.ndarray) -> np.ndarray:
            return (self.arrays(s + h)[2] - self.arrays(s - h)[2]) / (2 * h)

        return model_feedforward(v1 - v0, a1 - a0, jerk(t + dt) - jerk(t), dt, mass, plant)

    def sample(self, t: float) -> RefSample:
        p, v, a = self.arrays(np.array([t]))
        return RefSample(p=p[0], v=v[0], a=a[0])

    def states(self, t: np.ndarray) -> np.ndarray:
        """Reference states ``[p, v]`` (n, 6)."""
        p, v, _ = self.arrays(t)
        return np.hstack([p, v])
