"""VIO emulator: the error a visual-inertial odometry estimate makes, ``y = x + e``.

State ``x = [px, py, pz, vx, vy, vz]`` (world = motion-capture frame, z up). The error is
the sum of seven parts, each with its own switch in :class:`VioParams`::

    e_k = g * b(x_k)          smooth spatial bias field (known Lipschitz constant)
        + d_k                 drift that grows with the distance travelled
        + sigma(p_k) * n_k    white noise, larger where texture or light is poor
        + o_k                 occasional velocity outliers
        + blur, drift with motion, feature loss   (motion-dependent parts, below)
        + a scale error beyond the mapped region  (``region``, off by default: below)

**Bias field.** ``b(x) = sum_r A_r tanh((n_r . p - c_r) / w_r)          (ridges)
                     + sum_q A_q sin(k_q . p + phi_q)                   (ripples)
                     + [0, 0, 0, kappa * v]                             (velocity scale error)``
with ``n_r = (cos theta_r, sin theta_r, 0)`` a horizontal unit normal, ``A`` six amplitudes
(one per error component), ``k_q = (kx, ky)`` a horizontal wave vector. It is scaled by
``g = 1 + bias_light_gain * (1 - light)`` (VIO is worse in poor light).

**Lipschitz constant (infinity norm, closed form).** For each component ``i``,
``|b_i(x) - b_i(x')| <= sum_j sup|d b_i / d x_j| |x_j - x'_j| <= (sum_j sup|d b_i/d x_j|)
||x - x'||_inf``, and ``sup |d/dp_j tanh((n.p - c)/w)| = |n_j| / w``,
``sup |d/dp_j sin(k.p + phi)| = |k_j|``. Hence::

    L = g * max_i [ sum_r |A_ri| (|cos theta_r| + |sin theta_r|) / w_r
                  + sum_q |A_qi| (|kx_q| + |ky_q|) + |kappa_i| ]

so that ``||b(x) - b(x')||_inf <= L ||x - x'||_inf`` on the whole 6-D state. The default
ridges cross the default circle (radius 1 m about the origin), where one ridge dominates
its row, so a slope estimator on circle flights sees most of ``L``.

**Drift.** ``d_{k+1} = d_k + drift_fraction * u * ds_k + drift_walk * sqrt(ds_k) * N(0, I)``
on position only, ``ds_k = ||p_{k+1} - p_k||_2``, ``u`` a unit direction drawn per seed
(vertical part scaled by ``drift_vertical``).

**Noise.** ``sigma(p) = sigma_0 * (1 + noise_gain * (1 - light * texture(p)))`` with the floor
texture ``texture(p) = texture_level * clip(0.65 + 0.35 sin(2 pi px / lambda) cos(2 pi py /
lambda) - patch_depth * exp(-||p_xy - patch_center||^2 / (2 patch_radius^2)), 0.05, 1)``.

**Outliers.** With probability ``outlier_prob * (1 + noise_gain * (1 - light))`` per sample, one
velocity axis gets a spike of random sign and magnitude in ``[outlier_min, outlier_max]``.

``perception: degraded`` replaces ``light`` and ``texture_level`` by the ``degraded`` preset.

**Motion-dependent parts** (each with its own switch: ``blur``, ``motion_drift``,
``feature_loss``). They need the vehicle's true body rate ``omega_k`` (rad/s) and
acceleration ``a_k`` (m/s^2) at each sample (the closed loop passes them; without them they
are taken as zero). ``dt_v = 1 / rate_hz`` is the VIO sampling period.

*Motion blur.* The image blurs by ``b_k = t_exp f (||omega_k||_2 + ||v_xy,k||_2 / max(pz_k,
blur_min_height))`` pixels (rotation, and translation over a downward camera at height
``pz``), with exposure ``t_exp = min(blur_exposure_s / light, blur_exposure_max_s)`` (longer
in poor light) and focal length ``f = blur_focal_px``. Feature tracking degrades with it::

    e_k += b_k * sigma_b * nb_k         sigma_b = [blur_noise_position] * 3 + [blur_noise_velocity] * 3

and a velocity outlier (as above) with probability ``min(1, blur_outlier_rate * b_k)``.

*Drift with motion.* A second drift sum ``m_k`` on position, per radian turned and larger
per metre when fast (``dtheta_k = ||omega_k||_2 dt_v``, ``s_k = ||v_k||_2``)::

    m_{k+1} = m_k + drift_per_radian * u * dtheta_k + drift_walk_radian * sqrt(dtheta_k) * N(0, I)
                  + drift_speed_gain * s_k * (drift_fraction * u * ds_k + drift_walk * sqrt(ds_k) * N(0, I))

so the per-metre rate is ``drift_fraction (1 + drift_speed_gain s)`` with both sums on
(``dtheta = 0`` at a flight's first sample; ``u`` is the drift's direction).

*Feature loss.* While ``||omega_k||_2 > loss_rate_threshold`` or ``||a_k||_2 >
loss_accel_threshold``, a burst (a tracking loss and its recovery) starts with probability
``1 - exp(-loss_rate_hz (1 + loss_texture_gain (1 - light texture(p_k))) dt_v)`` per sample
(more often in poor texture) when no burst is running. It lasts ``m`` samples, ``m``
uniform among the whole numbers from ``loss_duration_s[0] / dt_v`` to ``loss_duration_s[1] /
dt_v`` (rounded), and adds ``A sin(pi (j + 1) / (m + 1))`` at its ``j``-th sample, ``A =
[loss_position] * 3 + [loss_velocity] * 3`` times uniforms in ``[-1, 1]``.

These parts are noise-like: the bias field and its Lipschitz constant ``L`` do not change.

**Mapped region** (``region``: centre ``c``, radius ``R``, ``slope``). Beyond the region the
horizontal position estimate takes ``slope max(0, rho - R) (p_xy - c) / rho``
(``rho = |p_xy - c|``): the error grows with the distance from what the estimator knows. Its
Jacobian is ``slope`` along ``p_hat`` and ``slope (rho - R) / rho`` across, so each row's
absolute sum is at most ``sqrt(2) slope``, added to ``L`` (docs/simulation.md).

Random parts come from independent streams of ``numpy.random.SeedSequence(seed)``, so
switching one part off leaves the others' values unchanged (and with the three motion parts
off and the first design's ridges, :data:`FIRST_RIDGES`, the errors are bit for bit those of
the emulator before the motion parts existed; the default ridges were recalibrated after);
the same seed gives the same errors.

The parameters (:class:`VioParams`, the ridges and ripples) are defined in
:mod:`qsls.pipeline.sim.options`, which loads no simulator, and re-exported here.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from qsls.pipeline.sim.options import FIRST_RIDGES as FIRST_RIDGES
from qsls.pipeline.sim.options import RIDGE_POSITION_SCALE as RIDGE_POSITION_SCALE
from qsls.pipeline.sim.options import RIDGE_VELOCITY_SCALE as RIDGE_VELOCITY_SCALE
from qsls.pipeline.sim.options import PerceptionLevel as PerceptionLevel
from qsls.pipeline.sim.options import Ridge as Ridge
from qsls.pipeline.sim.options import Ripple as Ripple
from qsls.pipeline.sim.options import Six as Six
from qsls.pipeline.sim.options import VioParams
from qsls.pipeline.sim.options import scaled_ridges as scaled_ridges
from qsls.pipeline.sim.viomotion import Burst, blur_pixels, burst_errors, velocity_spikes


def _dot2(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``p @ n.T`` for 2-vectors, row by row (no BLAS: the same bits for any batch size)."""
    return p[:, 0:1] * n[None, :, 0] + p[:, 1:2] * n[None, :, 1]


# Stream indices of the SeedSequence children (fixed: adding a stream appends).
_STREAM_NOISE, _STREAM_DRIFT, _STREAM_OUTLIER, _STREAM_DIRECTION = range(4)
_STREAM_BLUR_NOISE, _STREAM_BLUR_OUTLIER, _STREAM_MOTION_DRIFT, _STREAM_LOSS = range(4, 8)
_N_STREAMS = 8


class VioEmulator:
    """The VIO error model of the module docstring, seeded and deterministic.

    Stateless parts: :meth:`bias`, :meth:`texture`, :meth:`noise_std`, :meth:`blur`. Stateful
    per-sample model: :meth:`reset`, then :meth:`sample` once per VIO sample in time order
    (the drift sums integrate the motion between consecutive samples; a feature-loss burst
    carries over), or :meth:`errors` on a whole trajectory at once (identical values).
    """

    def __init__(self, params: VioParams, seed: int) -> None:
        self.params = params
        self.seed = int(seed)
        level = params.level
        self.light = float(level.light)
        self.texture_level = float(level.texture)
        self.bias_gain = 1.0 + params.bias_light_gain * (1.0 - self.light)
        self._ridge_n = np.array(
            [
                [np.cos(np.radians(r.normal_deg)), np.sin(np.radians(r.normal_deg))]
                for r in params.ridges
            ]
        ).reshape(-1, 2)
        self._ridge_c = np.array([r.offset for r in params.ridges], dtype=float)
        self._ridge_w = np.array([r.width for r in params.ridges], dtype=float)
        self._ridge_a = np.array([r.amplitude for r in params.ridges], dtype=float).reshape(-1, 6)
        self._rip_k = np.array([q.wavevector for q in params.ripples], dtype=float).reshape(-1, 2)
        self._rip_phi = np.array([q.phase for q in params.ripples], dtype=float)
        self._rip_a = np.array([q.amplitude for q in params.ripples], dtype=float).reshape(-1, 6)
        self._kappa = np.asarray(params.velocity_scale, dtype=float)
        self._sigma0 = np.array([params.noise_position] * 3 + [params.noise_velocity] * 3)
        self.outlier_prob = min(
            1.0, params.outlier_prob * (1.0 + params.noise_gain * (1.0 - self.light))
        )
        self.lipschitz = self._lipschitz()
        self.dt_v = 1.0 / params.rate_hz
        self.exposure_s = min(params.blur_exposure_s / self.light, params.blur_exposure_max_s)
        self._sigma_blur = np.array(
            [params.blur_noise_position] * 3 + [params.blur_noise_velocity] * 3
        )
        self._loss_peak = np.array([params.loss_position] * 3 + [params.loss_velocity] * 3)
        lo, hi = params.loss_duration_s
        self._loss_samples = (max(1, round(lo / self.dt_v)), max(1, round(hi / self.dt_v)))
        self.reset()

    # ------------------------------------------------------------------ bias field
    def _lipschitz(self) -> float:
        """``L`` of the module docstring (0 when the bias is switched off)."""
        if not self.params.bias:
            return 0.0
        rows = np.zeros(6)
        if len(self._ridge_w):
            per = np.abs(self._ridge_n).sum(axis=1) / self._ridge_w  # (R,)
            rows += (np.abs(self._ridge_a) * per[:, None]).sum(axis=0)
        if len(self._rip_phi):
            per = np.abs(self._rip_k).sum(axis=1)
            rows += (np.abs(self._rip_a) * per[:, None]).sum(axis=0)
        rows[3:] += np.abs(self._kappa)
        if self.params.region is not None:
            # the radial field's Jacobian: slope along p_hat, slope (rho - R) / rho < slope across;
            # a row's absolute sum is at most slope (|cos| + |sin|) <= sqrt(2) slope
            rows[:2] += np.sqrt(2.0) * self.params.region.slope / self.bias_gain
        return float(self.bias_gain * rows.max())

    def bias(self, x: np.ndarray) -> np.ndarray:
        """``g b(x)``: (n, 6) states to (n, 6) bias (zeros when the bias is off)."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        out = np.zeros((x.shape[0], 6))
        if not self.params.bias:
            return out
        pxy = x[:, :2]
        if len(self._ridge_w):
            s = np.tanh((_dot2(pxy, self._ridge_n) - self._ridge_c) / self._ridge_w)  # (n, R)
            out += (s[:, :, None] * self._ridge_a[None]).sum(axis=1)
        if len(self._rip_phi):
            s = np.sin(_dot2(pxy, self._rip_k) + self._rip_phi)
            out += (s[:, :, None] * self._rip_a[None]).sum(axis=1)
        out[:, 3:] += x[:, 3:6] * self._kappa
        out = self.bias_gain * out
        if self.params.region is not None:
            out[:, :2] += self.region_error(pxy)
        return out

    def region_error(self, pxy: np.ndarray) -> np.ndarray:
        """The scale error beyond the mapped region, ``slope max(0, rho - R) (p - c) / rho``
        (``rho = |p_xy - c|``), on the horizontal position: ``(n, 2)``."""
        reg = self.params.region
        assert reg is not None
        d = np.asarray(pxy, dtype=float) - np.asarray(reg.center, dtype=float)
        rho = np.hypot(d[:, 0], d[:, 1])
        out_m = np.maximum(rho - reg.radius, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = np.where(rho[:, None] > 0, d / rho[:, None], 0.0)
        return reg.slope * out_m[:, None] * unit

    # ------------------------------------------------------------------ texture and noise
    def texture(self, p: np.ndarray) -> np.ndarray:
        """Floor texture richness in [0.05, 1] times the level, at positions (n, >=2)."""
        p = np.atleast_2d(np.asarray(p, dtype=float))
        prm = self.params
        k = 2.0 * np.pi / prm.texture_wavelength
        base = 0.65 + 0.35 * np.sin(k * p[:, 0]) * np.cos(k * p[:, 1])
        d2 = ((p[:, :2] - np.asarray(prm.texture_patch_center)) ** 2).sum(axis=1)
        base -= prm.texture_patch_depth * np.exp(-d2 / (2.0 * prm.texture_patch_radius**2))
        return self.texture_level * np.clip(base, 0.05, 1.0)

    def noise_std(self, p: np.ndarray) -> np.ndarray:
        """Per-component noise std (n, 6) at positions (n, >=2)."""
        quality = self.light * self.texture(p)
        scale = 1.0 + self.params.noise_gain * (1.0 - quality)
        return scale[:, None] * self._sigma0[None, :]

    # ------------------------------------------------------------------ stateful model
    def reset(self) -> None:
        """Start a new flight: zero drift, fresh random streams for this seed."""
        # spawn(n) gives child i the same stream for any n >= i + 1: the first four are
        # the streams of the emulator before the motion parts existed
        ss = np.random.SeedSequence(self.seed).spawn(_N_STREAMS)
        self._rng_noise = np.random.default_rng(ss[_STREAM_NOISE])
        self._rng_drift = np.random.default_rng(ss[_STREAM_DRIFT])
        self._rng_out = np.random.default_rng(ss[_STREAM_OUTLIER])
        self._rng_blur = np.random.default_rng(ss[_STREAM_BLUR_NOISE])
        self._rng_blur_out = np.random.default_rng(ss[_STREAM_BLUR_OUTLIER])
        self._rng_mdrift = np.random.default_rng(ss[_STREAM_MOTION_DRIFT])
        self._rng_loss = np.random.default_rng(ss[_STREAM_LOSS])
        self._mdrift = np.zeros(3)
        self._burst = Burst()
        u = np.random.default_rng(ss[_STREAM_DIRECTION]).standard_normal(3)
        u[2] *= self.params.drift_vertical
        self.drift_direction = u / max(float(np.linalg.norm(u)), 1e-12)
        self._drift = np.zeros(3)
        self._last_p: np.ndarray | None = None
        self.distance = 0.0

    def sample(
        self, x: np.ndarray, omega: np.ndarray | None = None, accel: np.ndarray | None = None
    ) -> np.ndarray:
        """The error ``e`` (6,) of the next VIO sample at true state ``x`` (6,), body rate
        ``omega`` (3,) and acceleration ``accel`` (3,) (zero when not given)."""
        w = None if omega is None else np.asarray(omega, dtype=float).reshape(1, 3)
        a = None if accel is None else np.asarray(accel, dtype=float).reshape(1, 3)
        return self.errors(np.asarray(x, dtype=float).reshape(1, 6), w, a)[0]

    def errors(
        self, xs: np.ndarray, omega: np.ndarray | None = None, accel: np.ndarray | None = None
    ) -> np.ndarray:
        """Errors (n, 6) of the next ``n`` VIO samples at true states ``xs`` (n, 6), body
        rates ``omega`` (n, 3) and accelerations ``accel`` (n, 3) (zero when not given), in
        order.

        Continues the drift from previous calls; ``errors(xs)`` equals stacking
        ``sample(x)`` over the rows.
        """
        xs = np.atleast_2d(np.asarray(xs, dtype=float))
        n = xs.shape[0]
        prm = self.params
        # Random draws are made whether or not a part is on, so the streams stay aligned.
        z_noise = self._rng_noise.standard_normal((n, 6))
        z_drift = self._rng_drift.standard_normal((n, 3))
        u_out = self._rng_out.random((n, 3))  # [happens?, axis, magnitude]
        e = self.bias(xs)
        # drift
        p = xs[:, :3]
        started = self._last_p is not None
        prev = p[:1] if self._last_p is None else self._last_p[None, :]
        ds = np.linalg.norm(np.diff(np.vstack([prev, p]), axis=0), axis=1)
        steps = (
            prm.drift_fraction * ds[:, None] * self.drift_direction[None, :]
            + prm.drift_walk * np.sqrt(ds)[:, None] * z_drift
        )
        # cumsum from the previous value: the same additions, in the same order, as sample()
        drift = np.cumsum(np.vstack([self._drift[None, :], steps]), axis=0)[1:]
        self._drift = drift[-1].copy()
        self._last_p = p[-1].copy()
        self.distance += float(ds.sum())
        if prm.drift:
            e[:, :3] += drift
        if prm.noise:
            e += self.noise_std(p) * z_noise
        if prm.outliers:
            rows, spikes = velocity_spikes(
                u_out, u_out[:, 0] < self.outlier_prob, prm.outlier_min, prm.outlier_max
            )
            e[rows, 3:] += spikes
        w = np.zeros((n, 3)) if omega is None else np.asarray(omega, dtype=float).reshape(n, 3)
        a = np.zeros((n, 3)) if accel is None else np.asarray(accel, dtype=float).reshape(n, 3)
        self._motion_parts(e, xs, w, a, ds, started)
        return e

    def blur(self, xs: np.ndarray, omega: np.ndarray) -> np.ndarray:
        """Blur ``b_k`` (px) of the module docstring at states (n, 6) and body rates (n, 3)."""
        prm = self.params
        return blur_pixels(
            np.atleast_2d(xs), np.atleast_2d(omega), self.exposure_s, prm.blur_focal_px,
            prm.blur_min_height,
        )  # fmt: skip

    def _motion_parts(
        self, e: np.ndarray, xs: np.ndarray, w: np.ndarray, a: np.ndarray,
        ds: np.ndarray, started: bool,
    ) -> None:  # fmt: skip
        """Add blur, drift with motion and feature loss to ``e`` in place (module docstring)."""
        prm = self.params
        n = len(xs)
        z_blur = self._rng_blur.standard_normal((n, 6))
        u_blur = self._rng_blur_out.random((n, 3))
        z_md = self._rng_mdrift.standard_normal((n, 6))
        u_loss = self._rng_loss.random((n, 8))
        rate = np.sqrt((w * w).sum(axis=1))
        if prm.blur:
            b = self.blur(xs, w)
            e += b[:, None] * self._sigma_blur[None, :] * z_blur
            hit = u_blur[:, 0] < np.minimum(1.0, prm.blur_outlier_rate * b)
            rows, spikes = velocity_spikes(u_blur, hit, prm.outlier_min, prm.outlier_max)
            e[rows, 3:] += spikes
        dtheta = rate * self.dt_v
        if not started:
            dtheta[0] = 0.0  # the first sample of a flight has turned through nothing yet
        speed = np.sqrt((xs[:, 3:6] * xs[:, 3:6]).sum(axis=1))
        u = self.drift_direction[None, :]
        steps = (
            prm.drift_per_radian * dtheta[:, None] * u
            + prm.drift_walk_radian * np.sqrt(dtheta)[:, None] * z_md[:, :3]
            + (prm.drift_speed_gain * speed)[:, None]
            * (prm.drift_fraction * ds[:, None] * u + prm.drift_walk * np.sqrt(ds)[:, None] * z_md[:, 3:])
        )  # fmt: skip
        mdrift = np.cumsum(np.vstack([self._mdrift[None, :], steps]), axis=0)[1:]
        self._mdrift = mdrift[-1].copy()
        if prm.motion_drift:
            e[:, :3] += mdrift
        fast = (rate > prm.loss_rate_threshold) | (
            np.sqrt((a * a).sum(axis=1)) > prm.loss_accel_threshold
        )
        start = np.zeros(n)
        if fast.any():
            quality = self.light * self.texture(xs[fast])
            hz = prm.loss_rate_hz * (1.0 + prm.loss_texture_gain * (1.0 - quality))
            start[fast] = -np.expm1(-hz * self.dt_v)
        loss = burst_errors(self._burst, start, u_loss, self._loss_samples, self._loss_peak)
        if prm.feature_loss:
            e += loss

    def describe(self) -> dict[str, Any]:
        """Derived constants worth recording beside a flight (for ``truth.json``)."""
        return {
            "lipschitz": self.lipschitz,
            "bias_gain": self.bias_gain,
            "light": self.light,
            "texture_level": self.texture_level,
            "outlier_prob": self.outlier_prob,
            "drift_direction": [float(v) for v in self.drift_direction],
            "exposure_s": self.exposure_s,
        }
