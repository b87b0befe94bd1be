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
(p_f). Projecting on the left null space ``A`` of ``H_f`` removes the feature:
``r_o = A^T r = A^T H_x dx + A^T n`` (the multi-state constraint). Each feature passes a
chi-square gate ``r_o^T (H_o P H_o^T + s^2 I)^-1 r_o < chi2_q(2M - 3)``; the stacked
constraints are compressed by a thin QR when taller than the state, then the EKF update
(Joseph form). A feature is used when its track ends, or when the oldest clone leaves the
window (then every track seen in it is used and restarted, and the clone marginalized).

Functions of arrays, batched over the features that have the same number of observations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtri

from qsls.pipeline.sim.camera.geometry import skew, so3_exp
from qsls.pipeline.sim.camera.options import CameraOptions

I3 = np.eye(3)


@dataclass
class Track:
    clones: list[int] = field(default_factory=list)  # frame ids
    uv: list[tuple[float, float]] = field(default_factory=list)  # normalized image points


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
    b = np.einsum("fmij,fmj->fmi", rc, d)
    b /= np.linalg.norm(b, axis=2, keepdims=True)
    proj = (I3[None, None] - b[..., :, None] * b[..., None, :]) * w[..., None, None]
    a = proj.sum(axis=1)
    y = np.einsum("fmij,fmj->fi", proj, pc)
    ok = np.abs(np.linalg.det(a)) > 1e-9
    a[~ok] = I3
    pf = np.linalg.solve(a, y[..., None])[..., 0]
    rct = np.swapaxes(rc, 2, 3)
    valid = w > 0
    for _ in range(iters):
        x = np.einsum("fmij,fmj->fmi", rct, pf[:, None, :] - pc)  # in each camera
        zc = x[..., 2]
        ok &= ~((zc <= 1e-3) & valid).any(axis=1)
        zc = np.where(zc > 1e-3, zc, 1e-3)
        res = (z - x[..., :2] / zc[..., None]) * w[..., None]
        jp = np.zeros((f, m, 2, 3))
        jp[..., 0, 0] = w / zc
        jp[..., 1, 1] = w / zc
        jp[..., :, 2] = -x[..., :2] * (w / (zc * zc))[..., None]
        j = jp @ rct  # (F, M, 2, 3)
        jtj = np.einsum("fmki,fmkj->fij", j, j) + 1e-9 * I3
        jtr = np.einsum("fmki,fmk->fi", j, res)
        jtj[~ok] = I3
        pf = pf + np.linalg.solve(jtj, jtr[..., None])[..., 0]
    x = np.einsum("fmij,fmj->fmi", rct, pf[:, None, :] - pc)
    ok &= ((x[..., 2] > 0.05) | ~valid).all(axis=1) & np.isfinite(pf).all(axis=1)
    return pf, ok


def feature_constraints(
    rc: np.ndarray, pc: np.ndarray, z: np.ndarray, w: np.ndarray, pf: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Null-space projected residuals ``r_o`` (F, 2M-3) and Jacobians ``H_o`` (F, 2M-3, M, 6)
    on each feature's own clones (``dtheta_c, dp_c``), module docstring. Padding (``w = 0``)
    enters as rows of zeros: measurements ``0 = 0 dx + n`` that carry no information, so the
    projected constraints are those of the real observations (plus uninformative rows)."""
    f, m = z.shape[:2]
    rct = np.swapaxes(rc, 2, 3)
    dpw = pf[:, None, :] - pc  # (F, M, 3)
    x = np.einsum("fmij,fmj->fmi", rct, dpw)
    zc = x[..., 2]
    r = ((z - x[..., :2] / zc[..., None]) * w[..., None]).reshape(f, 2 * m)
    jp = np.zeros((f, m, 2, 3))
    jp[..., 0, 0] = w / zc
    jp[..., 1, 1] = w / zc
    jp[..., :, 2] = -x[..., :2] * (w / (zc * zc))[..., None]
    jr = jp @ rct  # J_pi R_c^T (F, M, 2, 3)
    sk = np.zeros((f, m, 3, 3))
    sk[..., 0, 1], sk[..., 0, 2] = -dpw[..., 2], dpw[..., 1]
    sk[..., 1, 0], sk[..., 1, 2] = dpw[..., 2], -dpw[..., 0]
    sk[..., 2, 0], sk[..., 2, 1] = -dpw[..., 1], dpw[..., 0]
    hx = np.zeros((f, m, 2, m, 6))
    idx = np.arange(m)
    hx[:, idx, :, idx, 0:3] = np.moveaxis(jr @ sk, 1, 0)
    hx[:, idx, :, idx, 3:6] = np.moveaxis(-jr, 1, 0)
    hf = jr.reshape(f, 2 * m, 3)
    q, _ = np.linalg.qr(hf, mode="complete")
    a = q[:, :, 3:]  # (F, 2M, 2M-3)
    ro = np.einsum("fki,fk->fi", a, r)
    ho = np.einsum("fki,fkj->fij", a, hx.reshape(f, 2 * m, 6 * m)).reshape(f, 2 * m - 3, m, 6)
    return ro, ho


class Msckf:
    """The filter of the module docstring."""

    def __init__(
        self, cam: CameraOptions, r_bc: np.ndarray, t_bc: np.ndarray, gravity: float,
        r0: np.ndarray, p0: np.ndarray, v0: np.ndarray,
    ) -> None:  # fmt: skip
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
        self.clone_ids: list[int] = []
        self.clone_R: list[np.ndarray] = []
        self.clone_p: list[np.ndarray] = []
        self.tracks: dict[int, Track] = {}
        self.sigma = cam.pixel_sigma / cam.focal_px
        self._phi = np.eye(15)
        self._q = np.zeros((15, 15))
        self.used_features = 0
        self.gated_features = 0
        self._gates: dict[int, float] = {}

    def _gate(self, dof: int) -> float:
        if dof not in self._gates:
            self._gates[dof] = float(chdtri(dof, 1.0 - self.cam.chi2_gate))
        return self._gates[dof]

    # ------------------------------------------------------------------ propagation
    def propagate(self, wm: np.ndarray, am: np.ndarray, h: float) -> None:
        """One IMU sample (module docstring); the covariance waits for the next frame."""
        cam = self.cam
        w = wm - self.bg
        a = am - self.ba
        r = self.R
        ra = r @ a
        acc = ra + self.g
        self.p = self.p + self.v * h + 0.5 * h * h * acc
        self.v = self.v + acc * h
        self.R = r @ so3_exp(w * h)
        fh = np.zeros((15, 15))
        fh[0:3, 9:12] = -r * h
        fh[3:6, 6:9] = I3 * h
        fh[6:9, 0:3] = -skew(ra) * h
        fh[6:9, 12:15] = -r * h
        phi = np.eye(15) + fh + 0.5 * (fh @ fh)
        self._phi = phi @ self._phi
        qd = np.zeros(15)
        qd[0:3] = cam.gyro_noise**2 * h
        qd[6:9] = cam.accel_noise**2 * h
        qd[9:12] = cam.gyro_walk**2 * h
        qd[12:15] = cam.accel_walk**2 * h
        self._q = phi @ self._q @ phi.T + np.diag(qd)

    def _apply_propagation(self) -> None:
        phi, P = self._phi, self.P
        P[:15, :15] = phi @ P[:15, :15] @ phi.T + self._q
        P[:15, 15:] = phi @ P[:15, 15:]
        P[15:, :15] = P[:15, 15:].T
        self._phi = np.eye(15)
        self._q = np.zeros((15, 15))

    def imu_covariance(self) -> np.ndarray:
        """The IMU block of ``P`` propagated to now (15, 15)."""
        return self._phi @ self.P[:15, :15] @ self._phi.T + self._q

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
        self.clone_R.append(self.R @ self.r_bc)
        self.clone_p.append(self.p + self.R @ self.t_bc)

    def process_frame(self, frame_id: int, ids: np.ndarray, uv: np.ndarray) -> None:
        """Propagate ``P`` to the frame, clone, add the observations ``uv`` (normalized, (n,
        2)) of features ``ids``, update with the finished tracks, slide the window."""
        self._apply_propagation()
        self._clone(frame_id)
        seen = set()
        for i, fid in enumerate(ids.tolist()):
            tr = self.tracks.get(fid)
            if tr is None:
                tr = self.tracks[fid] = Track()
            tr.clones.append(frame_id)
            tr.uv.append((float(uv[i, 0]), float(uv[i, 1])))
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
                        use.append(Track(tr.clones, tr.uv))
                    self.tracks[fid] = Track()
        if use:
            self._update(use)
        if oldest is not None:
            self._marginalize_oldest()

    def _marginalize_oldest(self) -> None:
        keep = np.r_[0:15, 21 : self.P.shape[0]]
        self.P = self.P[np.ix_(keep, keep)]
        del self.clone_ids[0], self.clone_R[0], self.clone_p[0]
        for tr in self.tracks.values():
            while tr.clones and tr.clones[0] < self.clone_ids[0]:
                del tr.clones[0], tr.uv[0]

    def _update(self, tracks: list[Track]) -> None:
        """EKF update with the tracks' constraints, all features in one batch (shorter
        tracks padded to the longest)."""
        pos = {c: i for i, c in enumerate(self.clone_ids)}
        crs = np.array(self.clone_R)
        cps = np.array(self.clone_p)
        n = self.P.shape[0]
        m = max(len(tr.clones) for tr in tracks)
        f = len(tracks)
        cidx = np.zeros((f, m), np.int64)
        z = np.zeros((f, m, 2))
        w = np.zeros((f, m))
        for i, tr in enumerate(tracks):
            k = len(tr.clones)
            cidx[i, :k] = [pos[c] for c in tr.clones]
            cidx[i, k:] = cidx[i, k - 1]
            z[i, :k] = tr.uv
            z[i, k:] = tr.uv[-1]
            w[i, :k] = 1.0
        rc, pc = crs[cidx], cps[cidx]
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
        cols = (15 + 6 * cidx[:, :, None] + np.arange(6)[None, None, :]).reshape(f, 6 * m)
        hc = ho.reshape(f, k, 6 * m)
        # gate on the feature's own clones: S = H_c P_cc H_c^T + s^2 I, dof 2 M_f - 3
        pcc = self.P[cols[:, :, None], cols[:, None, :]]
        s = hc @ pcc @ np.swapaxes(hc, 1, 2) + self.sigma**2 * np.eye(k)
        gamma = np.einsum("fi,fi->f", ro, np.linalg.solve(s, ro[..., None])[..., 0])
        dof = 2 * w.sum(axis=1).astype(int) - 3
        good = gamma < np.array([self._gate(int(d)) for d in dof])
        self.gated_features += int((~good).sum())
        g = int(good.sum())
        self.used_features += g
        if not g:
            return
        # padded observations scatter into six dummy columns past the state
        dummy = (w[good] == 0)[:, :, None].repeat(6, axis=2).reshape(g, 6 * m)
        cg = np.where(dummy, n + np.arange(6 * m)[None, :] % 6, cols[good])
        hfull = np.zeros((g, k, n + 6))
        hfull[np.arange(g)[:, None, None], np.arange(k)[None, :, None], cg[:, None, :]] = hc[good]
        h = hfull[:, :, :n].reshape(-1, n)
        r = ro[good].reshape(-1)
        if h.shape[0] > n:
            q, h = np.linalg.qr(h, mode="reduced")
            r = q.T @ r
        P = self.P
        pht = P @ h.T
        s2 = h @ pht + self.sigma**2 * np.eye(h.shape[0])
        gain = np.linalg.solve(s2, pht.T).T
        dx = gain @ r
        ikh = np.eye(n) - gain @ h
        self.P = ikh @ P @ ikh.T + self.sigma**2 * (gain @ gain.T)
        self.P = 0.5 * (self.P + self.P.T)
        self._correct(dx)

    def _correct(self, dx: np.ndarray) -> None:
        self.R = so3_exp(dx[0:3]) @ self.R
        self.p = self.p + dx[3:6]
        self.v = self.v + dx[6:9]
        self.bg = self.bg + dx[9:12]
        self.ba = self.ba + dx[12:15]
        for i in range(len(self.clone_ids)):
            o = 15 + 6 * i
            self.clone_R[i] = so3_exp(dx[o : o + 3]) @ self.clone_R[i]
            self.clone_p[i] = self.clone_p[i] + dx[o + 3 : o + 6]
