"""The multi-state constraint Kalman filter (Mourikis and Roumeliotis, ICRA 2007), monocular.

**State.** IMU: attitude ``R`` (body to world), position ``p``, velocity ``v``, gyroscope and
accelerometer biases ``b_g, b_a``; plus a sliding window of ``N`` camera clones ``(R_c, p_c)``
(camera to world). Error state ``dx = [dtheta, dp, dv, db_g, db_a, (dtheta_c, dp_c) x N]``
with ``R = exp(dtheta) R_hat`` (a world-frame attitude error) and additive errors elsewhere;
covariance ``P`` of size ``15 + 6 N``.

**Propagation** (per IMU sample ``(omega_m, a_m)`` over ``h``; ``w = omega_m - b_g``, ``a =
a_m - b_a``)::

    R <- R exp(w h),  v <- v + (R a + g) h,  p <- p + v h + (R a + g) h^2 / 2

Error dynamics ``dx' = F dx + G n``: ``dtheta' = -R db_g - R n_g``, ``dp' = dv``,
``dv' = -[R a]x dtheta - R db_a - R n_a``, ``db' = n_w``. Discrete ``Phi = I + F h + (F h)^2
/ 2``, ``Q = diag(s_g^2 h I, 0, s_a^2 h I, s_wg^2 h I, s_wa^2 h I)`` (white-noise densities
``s``: rotations leave isotropic noise unchanged). Products of ``Phi`` and sums of ``Q`` are
accumulated over a frame and applied to ``P`` once per frame: ``P_II <- Phi P_II Phi^T + Q``,
``P_IC <- Phi P_IC``.

**Clone** at each frame: ``R_c = R R_bc``, ``p_c = p + R t_bc``; ``P`` grows by ``J P J^T``
with ``dtheta_c = dtheta``, ``dp_c = dp - [R t_bc]x dtheta``.

**Update** with a feature ``f`` seen in clones ``j`` at normalized image points ``z_j``:
triangulate ``p_f`` (linear least squares on the rays, then Gauss-Newton on the reprojection
error), residuals ``r_j = z_j - pi(R_cj^T (p_f - p_cj))``, ``pi(x) = (x_1, x_2) / x_3``, with
Jacobians ``J_pi R_cj^T [p_f - p_cj]x`` (dtheta_cj), ``-J_pi R_cj^T`` (dp_cj) and ``J_pi R_cj^T``
(p_f). Each observation's rows are divided by its noise std ``s_j`` (per feature and frame,
:mod:`.noise`), so the noise is ``N(0, I)``. Projecting on the left null space ``A`` of
``H_f`` removes the feature: ``r_o = A^T r = A^T H_x dx + A^T n`` (the multi-state
constraint). Each feature passes a chi-square gate ``r_o^T (H_o P H_o^T + I)^-1 r_o <
chi2_q(2M - 3)``; the stacked
constraints (on the clone columns only: the IMU columns of ``H`` are zero) enter the EKF
update through ``H^T H`` and ``H^T r``, which is what a QR compression of a tall stack keeps,
at a fraction of its cost (``Msckf._ekf_update``); ``P <- P - K S K^T``, symmetrized. A feature is used when its track ends, or when the oldest clone leaves the
window (then every track seen in it is used and restarted, and the clone marginalized).

Functions of arrays, batched over the features that have the same number of observations.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtri

from qsls.pipeline.sim.camera.geometry import skew, so3_exp, so3_exp_many
from qsls.pipeline.sim.camera.options import CameraOptions

I3 = np.eye(3)


@dataclass
class Track:
    clones: list[int] = field(default_factory=list)  # frame ids
    uv: list[tuple[float, float]] = field(default_factory=list)  # normalized image points
    sig: list[float] = field(default_factory=list)  # their noise std (normalized units)


def _projection_jacobian(
    rct: np.ndarray, x: np.ndarray, w: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For points ``x`` (F, M, 3) in cameras with world-to-camera rotations ``rct`` (F, M, 3,
    3): the projections ``pi(x)`` (F, M, 2), the depths ``x_3`` (floored at 1 mm) and ``J_pi
    R_c^T`` (F, M, 2, 3) times the weights ``w``, written out as ``(R_c^T[:2] - pi(x)
    R_c^T[2]) / x_3`` (``J_pi = [I | -pi(x)] / x_3``)."""
    zc = np.where(x[..., 2] > 1e-3, x[..., 2], 1e-3)
    zh = x[..., :2] / zc[..., None]
    j = (rct[..., :2, :] - zh[..., :, None] * rct[..., 2:3, :]) * (w / zc)[..., None, None]
    return zh, zc, j


def triangulate(
    rc: np.ndarray, pc: np.ndarray, z: np.ndarray, w: np.ndarray, iters: int = 3
) -> tuple[np.ndarray, np.ndarray]:
    """Feature positions (F, 3) from rays: camera rotations ``rc`` (F, M, 3, 3), centres
    ``pc`` (F, M, 3), normalized points ``z`` (F, M, 2), weights ``w`` (F, M) (1: an
    observation, 0: padding); and a validity flag (F,) (depths positive, finite). Linear:
    ``sum_j (I - b_j b_j^T)(p_f - p_cj) = 0`` for unit rays ``b_j``; then ``iters``
    Gauss-Newton steps on the reprojection error."""
    f, m = z.shape[:2]
    d = np.concatenate([z, np.ones((f, m, 1))], axis=2)
    b = (rc @ d[..., None])[..., 0]
    b /= np.linalg.norm(b, axis=2, keepdims=True)
    proj = (I3 - b[..., :, None] * b[..., None, :]) * w[..., None, None]
    a = proj.sum(axis=1)
    y = (proj @ pc[..., None]).sum(axis=1)
    ok = np.abs(np.linalg.det(a)) > 1e-9
    a[~ok] = I3
    pf = np.linalg.solve(a, y)[..., 0]
    rct = np.swapaxes(rc, 2, 3)
    valid = w > 0
    for _ in range(iters):
        x = (rct @ (pf[:, None, :] - pc)[..., None])[..., 0]  # in each camera
        ok &= ~((x[..., 2] <= 1e-3) & valid).any(axis=1)
        zh, _, j = _projection_jacobian(rct, x, w)
        res = ((z - zh) * w[..., None]).reshape(f, 2 * m, 1)
        jf = j.reshape(f, 2 * m, 3)
        jt = np.swapaxes(jf, 1, 2)
        jtj = jt @ jf + 1e-9 * I3
        jtj[~ok] = I3
        pf = pf + np.linalg.solve(jtj, jt @ res)[..., 0]
    x = (rct @ (pf[:, None, :] - pc)[..., None])[..., 0]
    ok &= ((x[..., 2] > 0.05) | ~valid).all(axis=1) & np.isfinite(pf).all(axis=1)
    return pf, ok


def feature_constraints(
    rc: np.ndarray, pc: np.ndarray, z: np.ndarray, w: np.ndarray, pf: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Null-space projected residuals ``r_o`` (F, 2M-3) and Jacobians ``H_o`` (F, 2M-3, M, 6)
    on each feature's own clones (``dtheta_c, dp_c``), module docstring. Padding (``w = 0``)
    enters as rows of zeros: measurements ``0 = 0 dx + n`` that carry no information, so the
    projected constraints are those of the real observations (plus uninformative rows).

    ``H_x`` is block diagonal (observation ``j`` sees clone ``j`` only), so ``A^T H_x`` is
    taken block by block; ``v^T [d]x = (v x d)^T`` gives the attitude block row by row."""
    f, m = z.shape[:2]
    rct = np.swapaxes(rc, 2, 3)
    dpw = pf[:, None, :] - pc  # (F, M, 3)
    x = (rct @ dpw[..., None])[..., 0]
    zh, _, jr = _projection_jacobian(rct, x, w)  # jr = J_pi R_c^T (F, M, 2, 3)
    r = ((z - zh) * w[..., None]).reshape(f, 2 * m, 1)
    hb = np.empty((f, m, 2, 6))  # [J_pi R_c^T [d]x | -J_pi R_c^T], rows v^T [d]x = (v x d)^T
    d0, d1, d2 = dpw[..., None, 0], dpw[..., None, 1], dpw[..., None, 2]
    hb[..., 0] = jr[..., 1] * d2 - jr[..., 2] * d1
    hb[..., 1] = jr[..., 2] * d0 - jr[..., 0] * d2
    hb[..., 2] = jr[..., 0] * d1 - jr[..., 1] * d0
    hb[..., 3:] = -jr
    q, _ = np.linalg.qr(jr.reshape(f, 2 * m, 3), mode="complete")
    a = q[:, :, 3:]  # (F, 2M, 2M-3)
    k = 2 * m - 3
    ro = (np.swapaxes(a, 1, 2) @ r)[..., 0]
    ho = np.swapaxes(a.reshape(f, m, 2, k), 2, 3) @ hb  # (F, M, 2M-3, 6)
    return ro, np.swapaxes(ho, 1, 2)


def imu_transitions(
    r: np.ndarray, ra: np.ndarray, h: np.ndarray, cam: CameraOptions
) -> tuple[np.ndarray, np.ndarray]:
    """Per IMU sample ``k``: ``Phi_k = I + F h + (F h)^2 / 2`` (K, 15, 15) from the sample's
    attitude ``R`` (K, 3, 3), ``R a`` (K, 3) and step ``h`` (K,) (module docstring), and the
    diagonal of ``Q_k`` (K, 15). ``F h`` has the blocks ``-R h`` (dtheta <- db_g), ``I h``
    (dp <- dv), ``-[R a]x h`` (dv <- dtheta) and ``-R h`` (dv <- db_a); half its square adds
    ``-[R a]x h^2 / 2`` (dp <- dtheta), ``-R h^2 / 2`` (dp <- db_a) and ``[R a]x R h^2 / 2``
    (dv <- db_g), all written out here instead of multiplied."""
    k = len(h)
    hh = h[:, None, None]
    sk = np.zeros((k, 3, 3))
    sk[:, 0, 1], sk[:, 0, 2], sk[:, 1, 2] = -ra[:, 2], ra[:, 1], -ra[:, 0]
    sk[:, 1, 0], sk[:, 2, 0], sk[:, 2, 1] = ra[:, 2], -ra[:, 1], ra[:, 0]
    phi = np.zeros((k, 15, 15))
    idx = np.arange(15)
    phi[:, idx, idx] = 1.0
    rh = r * hh
    phi[:, 0:3, 9:12] = -rh
    phi[:, 3:6, 6:9] = I3 * hh
    phi[:, 3:6, 0:3] = -0.5 * sk * (hh * hh)
    phi[:, 3:6, 12:15] = -0.5 * rh * hh
    phi[:, 6:9, 0:3] = -sk * hh
    phi[:, 6:9, 9:12] = 0.5 * (sk @ r) * (hh * hh)
    phi[:, 6:9, 12:15] = -rh
    qd = np.zeros((k, 15))
    qd[:, 0:3] = (cam.gyro_noise**2 * h)[:, None]
    qd[:, 6:9] = (cam.accel_noise**2 * h)[:, None]
    qd[:, 9:12] = (cam.gyro_walk**2 * h)[:, None]
    qd[:, 12:15] = (cam.accel_walk**2 * h)[:, None]
    return phi, qd


class Msckf:
    """The filter of the module docstring."""

    def __init__(
        self, cam: CameraOptions, r_bc: np.ndarray, t_bc: np.ndarray, gravity: float,
        r0: np.ndarray, p0: np.ndarray, v0: np.ndarray,
    ) -> None:  # fmt: skip
        """Start at ``(r0, p0, v0)``, zero biases, covariance the initial prior of ``cam``
        (``init_sigma_*``; a re-initialization then widens its blocks in place)."""
        self.cam = cam
        self.r_bc, self.t_bc = r_bc, t_bc
        self.g = np.array([0.0, 0.0, -gravity])
        self.R, self.p, self.v = r0.copy(), p0.copy(), v0.copy()
        self.bg, self.ba = np.zeros(3), np.zeros(3)
        tilt, yaw = math.radians(cam.init_sigma_tilt_deg), math.radians(cam.init_sigma_yaw_deg)
        self.P = np.diag(
            [tilt**2, tilt**2, yaw**2]
            + [cam.init_sigma_position**2] * 3
            + [cam.init_sigma_velocity**2] * 3
            + [cam.init_sigma_gyro_bias**2] * 3
            + [cam.init_sigma_accel_bias**2] * 3
        )
        self.position_var0 = 0.0
        """``trace P_pp`` the filter started from (a re-initialized filter carries the lost
        one's position uncertainty): the covariance check measures what was added since."""
        self.clone_ids: list[int] = []
        self.clone_R = np.zeros((0, 3, 3))  # (N, 3, 3) camera to world
        self.clone_p = np.zeros((0, 3))  # (N, 3) camera centres
        self.tracks: dict[int, Track] = {}
        self.sigma = cam.pixel_sigma / cam.focal_px
        self._pending = 0  # IMU samples since the last frame
        self._pend_r = np.zeros((0, 3, 3))
        self._pend_ra = np.zeros((0, 3))
        self._pend_h = np.zeros(0)
        self.used_features = 0
        self.gated_features = 0
        self._gates: dict[int, float] = {}
        # (used, gated) per recent frame, for the innovation check of :meth:`health`
        self._recent: deque[tuple[int, int]] = deque(
            maxlen=max(1, round(cam.reset_window_s * cam.rate_hz))
        )

    def _gate(self, dof: int) -> float:
        if dof not in self._gates:
            self._gates[dof] = float(chdtri(dof, 1.0 - self.cam.chi2_gate))
        return self._gates[dof]

    # ------------------------------------------------------------------ propagation
    def propagate(self, wm: np.ndarray, am: np.ndarray, h: float) -> None:
        """One IMU sample (module docstring): the state now; the sample's ``R`` and ``R a``
        are kept so that the covariance is propagated once, at the next frame."""
        w = wm - self.bg
        a = am - self.ba
        r = self.R
        ra = r @ a
        acc = ra + self.g
        self.p = self.p + self.v * h + 0.5 * h * h * acc
        self.v = self.v + acc * h
        self.R = r @ so3_exp(w * h)
        k = self._pending
        if k == len(self._pend_h):
            grow = max(16, 2 * k)
            self._pend_r = np.concatenate([self._pend_r, np.zeros((grow - k, 3, 3))])
            self._pend_ra = np.concatenate([self._pend_ra, np.zeros((grow - k, 3))])
            self._pend_h = np.concatenate([self._pend_h, np.zeros(grow - k)])
        self._pend_r[k], self._pend_ra[k], self._pend_h[k] = r, ra, h
        self._pending = k + 1

    def _transition(self) -> tuple[np.ndarray, np.ndarray]:
        """``(Phi, Q)`` of the IMU samples since the last frame: ``Phi = Phi_K ... Phi_1``,
        ``Q = sum_k Phi_K..Phi_{k+1} Q_k (...)^T`` with the per-sample ``Phi_k``, ``Q_k`` of
        :func:`imu_transitions`."""
        k = self._pending
        if k == 0:
            return np.eye(15), np.zeros((15, 15))
        phis, qd = imu_transitions(self._pend_r[:k], self._pend_ra[:k], self._pend_h[:k], self.cam)
        phi, q = phis[0], np.diag(qd[0])
        for i in range(1, k):
            p_i = phis[i]
            phi = p_i @ phi
            q = p_i @ q @ p_i.T
            q[np.diag_indices(15)] += qd[i]
        return phi, q

    def _apply_propagation(self) -> None:
        phi, q = self._transition()
        self._pending = 0
        P = self.P
        P[:15, :15] = phi @ P[:15, :15] @ phi.T + q
        P[:15, 15:] = phi @ P[:15, 15:]
        P[15:, :15] = P[:15, 15:].T

    def imu_covariance(self) -> np.ndarray:
        """The IMU block of ``P`` propagated to now (15, 15)."""
        phi, q = self._transition()
        return phi @ self.P[:15, :15] @ phi.T + q

    # ------------------------------------------------------------------ a frame
    def _clone(self, frame_id: int) -> None:
        n = self.P.shape[0]
        j = np.zeros((6, n))
        j[0:3, 0:3] = I3
        j[3:6, 0:3] = -skew(self.R @ self.t_bc)
        j[3:6, 3:6] = I3
        pj = j @ self.P
        self.P = np.block([[self.P, pj.T], [pj, pj[:, :15] @ j[:, :15].T]])
        self.clone_ids.append(frame_id)
        self.clone_R = np.concatenate([self.clone_R, (self.R @ self.r_bc)[None]])
        self.clone_p = np.concatenate([self.clone_p, (self.p + self.R @ self.t_bc)[None]])

    def health(self) -> str | None:
        """Why the filter cannot be trusted any more, or None (checked after each frame):

        - innovations: over the last ``reset_window_s`` at least ``reset_min_gated``
          features failed the chi-square gate and they are at least ``reset_gated_fraction``
          of those that reached it (the camera contradicts the state: diverged);
        - covariance: ``sqrt(trace P_pp) > reset_sigma_position`` (lost: too long on the IMU
          alone), or a non-finite state or covariance.
        """
        cam = self.cam
        if not (np.isfinite(self.P).all() and np.isfinite(self.p).all()):
            return "non-finite state"
        used = sum(u for u, _ in self._recent)
        gated = sum(g for _, g in self._recent)
        if gated >= cam.reset_min_gated and gated >= cam.reset_gated_fraction * (used + gated):
            return (
                f"innovations: {gated} of {used + gated} features rejected by the gate in "
                f"{cam.reset_window_s:g} s"
            )
        # position and yaw are unobservable: a re-initialized filter keeps the lost one's
        # uncertainty (position_var0), so only the growth since its start marks it lost
        sigma = math.sqrt(max(float(np.trace(self.P[3:6, 3:6])) - self.position_var0, 0.0))
        if sigma > cam.reset_sigma_position:
            return f"covariance: position std {sigma:.2f} m"
        return None

    def process_frame(
        self, frame_id: int, ids: np.ndarray, uv: np.ndarray, sigma: np.ndarray | None = None
    ) -> None:
        """Propagate ``P`` to the frame, clone, add the observations ``uv`` (normalized, (n,
        2)) of features ``ids`` with noise std ``sigma`` (n,) (normalized; None: the fixed
        ``pixel_sigma``), update with the finished tracks, slide the window."""
        u0, g0 = self.used_features, self.gated_features
        sig = np.full(len(ids), self.sigma) if sigma is None else sigma
        self._frame(frame_id, ids, uv, sig)
        self._recent.append((self.used_features - u0, self.gated_features - g0))

    def _frame(self, frame_id: int, ids: np.ndarray, uv: np.ndarray, sig: np.ndarray) -> None:
        self._apply_propagation()
        self._clone(frame_id)
        seen = set()
        for i, (fid, s) in enumerate(zip(ids.tolist(), sig.tolist(), strict=True)):
            tr = self.tracks.get(fid)
            if tr is None:
                tr = self.tracks[fid] = Track()
            tr.clones.append(frame_id)
            tr.uv.append((float(uv[i, 0]), float(uv[i, 1])))
            tr.sig.append(s)
            seen.add(fid)
        use: list[Track] = []
        for fid in [k for k in self.tracks if k not in seen]:
            tr = self.tracks.pop(fid)
            if len(tr.clones) >= self.cam.min_track:
                use.append(tr)
        oldest = None
        if len(self.clone_ids) > self.cam.window:
            oldest = self.clone_ids[0]
            for fid, tr in self.tracks.items():
                if tr.clones and tr.clones[0] == oldest:
                    if len(tr.clones) >= self.cam.min_track:
                        use.append(Track(tr.clones, tr.uv, tr.sig))
                    self.tracks[fid] = Track()
        if use:
            self._update(use)
        if oldest is not None:
            self._marginalize_oldest()

    def _marginalize_oldest(self) -> None:
        keep = np.r_[0:15, 21 : self.P.shape[0]]
        self.P = self.P[np.ix_(keep, keep)]
        del self.clone_ids[0]
        self.clone_R, self.clone_p = self.clone_R[1:], self.clone_p[1:]
        for tr in self.tracks.values():
            while tr.clones and tr.clones[0] < self.clone_ids[0]:
                del tr.clones[0], tr.uv[0], tr.sig[0]

    def _update(self, tracks: list[Track]) -> None:
        """EKF update with the tracks' constraints, all features in one batch (shorter
        tracks padded to the longest).

        ``H`` is zero on the IMU state (a feature constrains the clones only), so the
        constraints are stacked on the clone columns ``H_c`` alone (:meth:`_ekf_update`)."""
        nc = len(self.clone_ids)
        pos = {c: i for i, c in enumerate(self.clone_ids)}
        m = max(len(tr.clones) for tr in tracks)
        f = len(tracks)
        cidx = np.zeros((f, m), np.int64)
        z = np.zeros((f, m, 2))
        w = np.zeros((f, m))  # 1 / noise std of each observation (whitening), 0: padding
        for i, tr in enumerate(tracks):
            k = len(tr.clones)
            cidx[i, :k] = [pos[c] for c in tr.clones]
            cidx[i, k:] = cidx[i, k - 1]
            z[i, :k] = tr.uv
            z[i, k:] = tr.uv[-1]
            w[i, :k] = 1.0 / np.asarray(tr.sig)
        rc, pc = self.clone_R[cidx], self.clone_p[cidx]
        span = np.linalg.norm(pc - pc.mean(axis=1, keepdims=True), axis=2).max(axis=1)
        pf, ok = triangulate(rc, pc, z, w)
        depth = np.linalg.norm(pf - pc.mean(axis=1), axis=1)
        ok &= 2.0 * span > self.cam.min_parallax_ratio * depth
        if not ok.any():
            return
        rc, pc, z, w, pf, cidx = rc[ok], pc[ok], z[ok], w[ok], pf[ok], cidx[ok]
        ro, ho = feature_constraints(rc, pc, z, w, pf)
        f = len(ro)
        k = 2 * m - 3
        cols = (6 * cidx[:, :, None] + np.arange(6)[None, None, :]).reshape(f, 6 * m)
        hc = ho.reshape(f, k, 6 * m)
        # gate on the feature's own clones: S = H_c P_cc H_c^T + I (whitened), dof 2 M_f - 3
        pcc = self.P[15:, 15:][cols[:, :, None], cols[:, None, :]]
        s = hc @ pcc @ np.swapaxes(hc, 1, 2) + np.eye(k)
        gamma = np.einsum("fi,fi->f", ro, np.linalg.solve(s, ro[..., None])[..., 0])
        dof = 2 * (w > 0).sum(axis=1) - 3
        good = gamma < np.array([self._gate(int(d)) for d in dof])
        self.gated_features += int((~good).sum())
        g = int(good.sum())
        self.used_features += g
        if not g:
            return
        # padded observations (zero blocks) go to a dummy clone past the window, so that they
        # do not overwrite the real block of the clone they repeat
        ci = np.where(w[good] > 0, cidx[good], nc)
        hs = np.zeros((g, k, nc + 1, 6))
        hs[np.arange(g)[:, None], :, ci, :] = np.swapaxes(ho[good], 1, 2)
        h = hs[:, :, :nc, :].reshape(g * k, 6 * nc)
        r = ro[good].reshape(-1)
        self._ekf_update(h.T @ h, h.T @ r)

    def _ekf_update(self, m: np.ndarray, b: np.ndarray) -> None:
        """EKF update with the stacked constraints ``r = H_c dx_c + n`` on the clone columns,
        given as ``M = H_c^T H_c`` and ``b = H_c^T r`` (``_update``), whitened (each
        observation's rows divided by its noise std, so the noise is ``N(0, I)``). With the
        push-through identity ``H_c^T (H_c P_cc H_c^T + I)^-1 = (M P_cc + I)^-1 H_c^T``::

            X = (M P_cc + I)^-1 [b | M P_c:],   dx = P_:c X_b,   P <- P - P_:c X_P

        (``K r`` and ``K S K^T = K H P`` of the Kalman update), then ``P`` symmetrized. This
        is the update after a QR compression of ``H_c`` (the same ``M`` and ``b``) without
        the QR: a stack of a few hundred rows costs one ``H^T H``."""
        P = self.P
        pc = P[15:]  # P_c: (6 N, n)
        a = m @ pc[:, 15:]
        a[np.diag_indices_from(a)] += 1.0  # the constraints are whitened (unit noise)
        x = np.linalg.solve(a, np.column_stack([b, m @ pc]))
        dx = pc.T @ x[:, 0]
        self.P = P - pc.T @ x[:, 1:]
        self.P = 0.5 * (self.P + self.P.T)
        self._correct(dx)

    def _correct(self, dx: np.ndarray) -> None:
        self.R = so3_exp(dx[0:3]) @ self.R
        self.p = self.p + dx[3:6]
        self.v = self.v + dx[6:9]
        self.bg = self.bg + dx[9:12]
        self.ba = self.ba + dx[12:15]
        dc = dx[15:].reshape(-1, 6)
        self.clone_R = so3_exp_many(dc[:, :3]) @ self.clone_R
        self.clone_p = self.clone_p + dc[:, 3:]
