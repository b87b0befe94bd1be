"""Visual-inertial initialization in closed form (Martinelli, IJCV 2014; Kaiser, Martinelli,
Fontana and Scaramuzza, RA-L 2017): velocity, gravity and feature distances from a short
window of IMU samples and tracked bearings, by linear least squares. No state estimate and
no truth enters: only the measurements.

**Preintegration.** In the body frame of the window's first frame (``R_00 = I``), the
gyroscope gives the attitudes ``R_0k`` and the accelerometer (biases taken as zero) the
integrals, with the filter's integration scheme (:meth:`.msckf.Msckf.propagate`)::

    R_0,k+1 = R_0k exp(w_k h),   V_k+1 = V_k + R_0k a_k h,   S_k+1 = S_k + V_k h + R_0k a_k h^2 / 2

so that the body position at time ``t`` after the first frame is ``P(t) = v_0 t + g_0 t^2 / 2 +
S(t)`` with the unknown velocity ``v_0`` and gravity ``g_0`` in that frame.

**Bearings.** Feature ``i`` seen at frame ``j`` (normalized point ``z_ij``) lies along
``b_ij = R_0j R_bc [z_ij, 1]`` from the camera centre ``C_j = P(t_j) + R_0j t_bc``. Anchored at
its first frame ``a`` in the window at the unknown distance ``lambda_i`` along ``b_ia``, the
ray of every later frame must pass through it: for the two unit vectors ``T_ij`` (2, 3)
orthogonal to ``b_ij``::

    T_ij (lambda_i b_ia + v_0 (t_a - t_j) + g_0 (t_a^2 - t_j^2) / 2)
        = T_ij (S_j + R_0j t_bc - S_a - R_0a t_bc)

two equations linear in ``x = [v_0, g_0, lambda_1..lambda_F]`` per observation: the
perpendicular miss (m) of the ray, divided by the distance to the feature (a second pass,
with the first pass's distances) and by the observation's noise std, so that each row is a
whitened angle. Then ``||g_0|| = g`` is imposed as VINS-Mono refines gravity: ``g_0 = g n +
B delta`` with ``B`` (3, 2) orthogonal to the current direction ``n``, solve for ``[v_0,
delta, lambda]``, ``n <- (g n + B delta) / ||.||``, three times.

**Refinement.** The linear rows take each feature's anchor bearing as exact; at real noise
levels that biases them (0.3 px of noise: 0.6 m/s^2 of gravity error on a 1 s window of the
figure eight). So the linear solution only starts a Gauss-Newton refinement of the whitened
reprojection errors ``(z_ij - pi(R_cj^T (X_i - C_j))) / sigma_ij`` over ``v_0``, the gravity
direction (two tangent coordinates) and the feature positions ``X_i``, the features
eliminated by their 3x3 blocks (Schur complement): the maximum-likelihood estimate given the
gyroscope's rotations (0.3 px: 0.02 m/s^2, 0.02 m/s).

**Conditioning.** The refined solution's covariance (the inverse of the Schur complement,
times the squared RMS of the whitened residuals when above 1, times ``sigma_scale^2``: the
least squares takes the observations' errors as independent, a KLT track's are not) gives
the standard deviations of the velocity now and of the tilt; the solution is refused (and retried at a later frame, the filter meanwhile running on
the IMU) when too few features were tracked over the window, when either std is above its
bound, when the unconstrained gravity's norm is off by more than 10%, when the residuals are
too large for the assumed noise (outliers or a wrong model), or when features lie behind the
camera. Too little motion shows as a large velocity or tilt std.

**State now.** The latest frame's attitude ``R_0M`` and velocity ``v_M = v_0 + g_0 t_M + V_M``
(in frame 0); the rotation from frame 0 to the world is the smallest one that takes ``g_0``
to ``(0, 0, -g)``, times a rotation about the vertical chosen by the caller (the yaw, which no
initialization observes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from qsls.pipeline.sim.camera.geometry import so3_exp

I3 = np.eye(3)


@dataclass(frozen=True)
class InitSolution:
    """A closed-form initialization at the window's latest frame (module docstring)."""

    r_0m: np.ndarray
    """(3, 3) body attitude at the latest frame in the first frame's body axes."""
    g0: np.ndarray
    """(3,) gravity in the first frame's body axes (norm ``g``)."""
    v_m: np.ndarray
    """(3,) velocity at the latest frame, in the first frame's body axes."""
    cov_v: np.ndarray
    """(3, 3) covariance of ``v_m`` (first frame's axes)."""
    sigma_tilt: float
    """Largest std of the gravity direction (rad)."""
    features: int
    residual_rms: float
    """RMS of the whitened residuals (about 1 when the noise model holds)."""


@dataclass(frozen=True)
class InitRefusal:
    """Why a window did not give a trustworthy initialization."""

    why: str


def preintegrate(
    wm: np.ndarray, am: np.ndarray, h: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(R_0k, V_k, S_k, t_k)`` for ``k = 0..K`` of IMU samples ``wm, am`` (K, 3) over steps
    ``h`` (K,) (module docstring)."""
    k = len(h)
    rs = np.empty((k + 1, 3, 3))
    vs = np.zeros((k + 1, 3))
    ss = np.zeros((k + 1, 3))
    r = I3.copy()
    rs[0] = r
    for i in range(k):
        hi = float(h[i])
        ra = r @ am[i]
        ss[i + 1] = ss[i] + vs[i] * hi + 0.5 * hi * hi * ra
        vs[i + 1] = vs[i] + ra * hi
        r = r @ so3_exp(wm[i] * hi)
        rs[i + 1] = r
    return rs, vs, ss, np.concatenate([[0.0], np.cumsum(h)])


def _tangent(b: np.ndarray) -> np.ndarray:
    """Two unit vectors (n, 2, 3) orthogonal to each unit vector ``b`` (n, 3)."""
    helper = np.where(np.abs(b[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(b, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(b, t1)
    return np.stack([t1, t2], axis=1)


def _basis(n: np.ndarray) -> np.ndarray:
    """(3, 2): two unit vectors orthogonal to the unit vector ``n``."""
    return _tangent(n[None])[0].T


def closed_form_init(
    wm: np.ndarray,
    am: np.ndarray,
    h: np.ndarray,
    frame_sample: np.ndarray,
    obs_frame: np.ndarray,
    obs_feature: np.ndarray,
    obs_uv: np.ndarray,
    obs_sigma: np.ndarray,
    r_bc: np.ndarray,
    t_bc: np.ndarray,
    gravity: float,
    *,
    min_features: int = 20,
    max_sigma_velocity: float = 0.1,
    max_sigma_tilt: float = math.radians(2.0),
    max_residual: float = 3.0,
    sigma_scale: float = 1.0,
) -> InitSolution | InitRefusal:
    """Solve the window (module docstring).

    ``wm, am, h``: IMU samples from the window's first frame to its last; ``frame_sample``
    (M,): the sample index of each frame (0 for the first, K for the last);
    observations: frame index ``obs_frame`` (n,), feature id ``obs_feature`` (n,),
    normalized point ``obs_uv`` (n, 2) and its noise std ``obs_sigma`` (n,) (normalized).
    Features seen in fewer than 3 frames of the window are not used. ``sigma_scale``
    multiplies the reported standard deviations (the least squares takes the observations'
    errors as independent; a KLT track's are not, docs/camera.md).
    """
    with np.errstate(all="ignore"):
        try:
            return _solve(
                wm, am, h, frame_sample, obs_frame, obs_feature, obs_uv, obs_sigma, r_bc,
                t_bc, gravity, min_features, max_sigma_velocity, max_sigma_tilt, max_residual,
                sigma_scale,
            )  # fmt: skip
        except np.linalg.LinAlgError:
            return InitRefusal("singular normal equations (no motion or no parallax)")


def _solve(
    wm: np.ndarray, am: np.ndarray, h: np.ndarray, frame_sample: np.ndarray,
    obs_frame: np.ndarray, obs_feature: np.ndarray, obs_uv: np.ndarray,
    obs_sigma: np.ndarray, r_bc: np.ndarray, t_bc: np.ndarray, gravity: float,
    min_features: int, max_sigma_velocity: float, max_sigma_tilt: float,
    max_residual: float, sigma_scale: float,
) -> InitSolution | InitRefusal:  # fmt: skip
    rs, vs, ss, ts = preintegrate(wm, am, h)
    rf, sf, tf = rs[frame_sample], ss[frame_sample], ts[frame_sample]
    # features seen at least 3 times, observations sorted by feature then frame
    order = np.lexsort((obs_frame, obs_feature))
    fid, fr = obs_feature[order], obs_frame[order]
    uv, sig = obs_uv[order], obs_sigma[order]
    ufid, start, count = np.unique(fid, return_index=True, return_counts=True)
    keep_f = count >= 3
    if keep_f.sum() < min_features:
        return InitRefusal(f"{int(keep_f.sum())} features tracked over the window")
    col = np.full(len(ufid), -1)
    col[keep_f] = np.arange(int(keep_f.sum()))
    fcol = np.repeat(col, count)
    anchor = np.repeat(start, count)  # index of each observation's anchor observation
    use = (fcol >= 0) & (np.arange(len(fid)) != anchor)
    nf = int(keep_f.sum())
    # bearings in the first frame's body axes
    d = np.concatenate([uv, np.ones((len(uv), 1))], axis=1) @ r_bc.T
    b = (rf[fr] @ d[..., None])[..., 0]
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    cam_off = sf + (rf @ t_bc)  # S_j + R_0j t_bc (M, 3)
    j_, a_ = fr[use], fr[anchor[use]]
    bj, ba = b[use], b[anchor[use]]
    dt = (tf[a_] - tf[j_])[:, None]
    dt2 = 0.5 * (tf[a_] ** 2 - tf[j_] ** 2)[:, None]
    rhs3 = cam_off[j_] - cam_off[a_]
    a_full, y_full = _linear_rows(bj, ba, dt, dt2, rhs3, fcol[use], nf)
    ridge = 1e-9 * np.eye(6 + nf)
    # pass 1: weights from a nominal 1 m distance; pass 2: from the solved distances
    wgt = 1.0 / sig[use]
    x = _wls(a_full, y_full, wgt, ridge)
    lam = x[6:]
    dist = _distances(lam, fcol[use], ba, x[0:3], x[3:6], dt, dt2, rhs3)
    if not np.isfinite(dist).all():
        return InitRefusal("degenerate geometry")
    wgt = 1.0 / (sig[use] * np.maximum(dist, 0.1))
    x = _wls(a_full, y_full, wgt, ridge)
    g_free = float(np.linalg.norm(x[3:6]))
    if not math.isfinite(g_free) or abs(g_free - gravity) > 0.1 * gravity:
        return InitRefusal(f"gravity norm {g_free:.2f} m/s^2 from the window")
    x2, g0 = _on_gravity_sphere(a_full, y_full, wgt, ridge, x[3:6] / g_free, gravity)
    # Gauss-Newton on the reprojection errors (the linear rows treat the anchor bearing as
    # exact, which biases them at real noise levels): unknowns v_0, delta, the features
    x0 = _features(x2[5:], fcol[use], ba, x2[0:3], g0, tf[a_], cam_off[a_], nf)
    ref = _refine(x2[0:3], g0, x0, rf, tf, cam_off, r_bc, fr[fcol >= 0], fcol[fcol >= 0],
                  uv[fcol >= 0], sig[fcol >= 0], gravity)  # fmt: skip
    if ref is None:
        return InitRefusal("refinement failed")
    v0, g0, xf, cov, rms = ref
    cov = sigma_scale**2 * cov
    v_m, cov_v, sig_v, sig_tilt = _at_last_frame(
        v0, g0, cov, float(tf[-1]), vs[frame_sample[-1]], gravity
    )
    depth = ((xf[fcol[use]] - _centres(v0, g0, tf[j_], cam_off[j_])) * bj).sum(axis=1)
    if rms > max_residual:
        return InitRefusal(f"residuals {rms:.1f} times the assumed noise")
    if np.mean(depth > 0) < 0.9:
        return InitRefusal("features behind the camera")
    if sig_v > max_sigma_velocity:
        return InitRefusal(f"velocity std {sig_v:.3f} m/s (too little motion or parallax)")
    if sig_tilt > max_sigma_tilt:
        return InitRefusal(f"tilt std {math.degrees(sig_tilt):.2f} deg")
    return InitSolution(
        r_0m=rs[frame_sample[-1]], g0=g0, v_m=v_m, cov_v=cov_v, sigma_tilt=sig_tilt,
        features=nf, residual_rms=rms,
    )  # fmt: skip


def _linear_rows(
    bj: np.ndarray,
    ba: np.ndarray,
    dt: np.ndarray,
    dt2: np.ndarray,
    rhs3: np.ndarray,
    feature_col: np.ndarray,
    nf: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The unwhitened rows ``T (v0 dt + g0 dt2 + lambda_f b_a) = T rhs3``, two per
    observation (``T`` the two unit vectors normal to its bearing ``b_j``), over the unknowns
    ``(v0, g0, lambda_1..nf)``: ``(n, 2, 6 + nf)`` and ``(n, 2)``."""
    tj = _tangent(bj)  # (n, 2, 3)
    n = len(bj)
    a_full = np.zeros((n, 2, 6 + nf))
    a_full[:, :, 0:3] = tj * dt[:, :, None]
    a_full[:, :, 3:6] = tj * dt2[:, :, None]
    a_full[np.arange(n), :, 6 + feature_col] = np.einsum("nkc,nc->nk", tj, ba)
    return a_full, np.einsum("nkc,nc->nk", tj, rhs3)


def _on_gravity_sphere(
    a_full: np.ndarray,
    y_full: np.ndarray,
    wgt: np.ndarray,
    ridge: np.ndarray,
    nvec: np.ndarray,
    gravity: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The weighted rows solved again with ``||g0|| = g``: ``g0 = g n + B delta`` (``B`` two
    unit vectors normal to ``n``), ``n`` updated from the solution, three times; the last
    solution ``(v_0, delta, lambda)`` and ``g0 = g n``."""
    n, _, cols = a_full.shape
    aw = a_full * wgt[:, None, None]
    yw = y_full * wgt[:, None]
    for _ in range(3):
        bb = _basis(nvec)
        a2 = np.concatenate(
            [aw[:, :, 0:3], np.einsum("nkc,cd->nkd", aw[:, :, 3:6], bb), aw[:, :, 6:]], axis=2
        ).reshape(2 * n, cols - 1)
        y2 = (yw - np.einsum("nkc,c->nk", aw[:, :, 3:6], gravity * nvec)).reshape(-1)
        ata = a2.T @ a2 + ridge[1:, 1:]
        x2 = np.linalg.solve(ata, a2.T @ y2)
        g0 = gravity * nvec + bb @ x2[3:5]
        nvec = g0 / np.linalg.norm(g0)
    return x2, gravity * nvec


def _at_last_frame(
    v0: np.ndarray, g0: np.ndarray, cov: np.ndarray, t_m: float, dv_m: np.ndarray, gravity: float
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The velocity at the window's last frame ``v_m = v_0 + g0 t_m + dv_m`` (``dv_m`` the
    preintegrated velocity), its covariance ``J cov J^T`` with ``J = [I, t_m B]`` from the
    covariance of ``(v_0, delta)``, its largest std, and the tilt's std (``delta``'s largest,
    over ``g``)."""
    bb = _basis(g0 / gravity)
    v_m = v0 + g0 * t_m + dv_m
    jac = np.zeros((3, 5))
    jac[:, 0:3] = I3
    jac[:, 3:5] = t_m * bb
    cov_v = jac @ cov @ jac.T
    sig_v = math.sqrt(max(float(np.linalg.eigvalsh(cov_v)[-1]), 0.0))
    sig_tilt = math.sqrt(max(float(np.linalg.eigvalsh(cov[3:5, 3:5])[-1]), 0.0)) / gravity
    return v_m, cov_v, sig_v, sig_tilt


def _wls(a: np.ndarray, y: np.ndarray, wgt: np.ndarray, ridge: np.ndarray) -> np.ndarray:
    """Weighted least squares of the rows ``a`` (n, 2, c), ``y`` (n, 2), weights (n,)."""
    aw = (a * wgt[:, None, None]).reshape(-1, a.shape[2])
    yw = (y * wgt[:, None]).reshape(-1)
    return np.linalg.solve(aw.T @ aw + ridge, aw.T @ yw)


def _distances(
    lam: np.ndarray, fcol: np.ndarray, ba: np.ndarray, v0: np.ndarray, g0: np.ndarray,
    dt: np.ndarray, dt2: np.ndarray, rhs3: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """Distance from each observing camera to its feature: ``||lambda b_a + v0 dt + g0 dt2 -
    rhs||`` (the feature relative to the camera centre, module docstring)."""
    rel = lam[fcol][:, None] * ba + v0 * dt + g0 * dt2 - rhs3
    return np.linalg.norm(rel, axis=1)


def world_from_first(g0: np.ndarray) -> np.ndarray:
    """The smallest rotation ``R_w0`` with ``R_w0 g0 / ||g0|| = (0, 0, -1)``."""
    n = g0 / np.linalg.norm(g0)
    down = np.array([0.0, 0.0, -1.0])
    axis = np.cross(n, down)
    s, c = float(np.linalg.norm(axis)), float(n @ down)
    if s < 1e-12:
        return I3.copy() if c > 0 else np.diag([1.0, -1.0, -1.0])
    return so3_exp(axis / s * math.atan2(s, c))


def _centres(v0: np.ndarray, g0: np.ndarray, t: np.ndarray, off: np.ndarray) -> np.ndarray:
    """Camera centres in the first frame's axes at times ``t``: ``C_j = v_0 t_j + g_0 t_j^2 / 2
    + S_j + R_0j t_bc`` (``off`` the last two terms)."""
    return v0 * t[:, None] + 0.5 * g0 * (t**2)[:, None] + off


def _features(
    lam: np.ndarray, fcol: np.ndarray, ba: np.ndarray, v0: np.ndarray, g0: np.ndarray,
    ta: np.ndarray, off_a: np.ndarray, nf: int,
) -> np.ndarray:  # fmt: skip
    """Feature positions (nf, 3) in the first frame's axes from the linear solution: ``C_a +
    lambda b_a`` (distances floored at 5 cm)."""
    ca = _centres(v0, g0, ta, off_a)
    out = np.zeros((nf, 3))
    out[fcol] = ca + np.maximum(lam[fcol], 0.05)[:, None] * ba
    return out


def _refine(
    v0: np.ndarray, g0: np.ndarray, xf: np.ndarray, rf: np.ndarray, tf: np.ndarray,
    cam_off: np.ndarray, r_bc: np.ndarray, fr: np.ndarray, fc: np.ndarray, uv: np.ndarray,
    sig: np.ndarray, gravity: float, iters: int = 6,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float] | None:  # fmt: skip
    """Gauss-Newton on the whitened reprojection errors ``(z - pi(R_cj^T (X_i - C_j))) /
    sigma`` with ``C_j = v_0 t_j + g_0 t_j^2 / 2 + S_j + R_0j t_bc``, ``g_0 = g n`` moved in
    its tangent plane, the features ``X_i`` eliminated by their 3x3 blocks (Schur
    complement). Returns ``v_0, g_0, X``, the covariance (5, 5) of ``[v_0, delta]``
    (scaled by the residuals' RMS when above 1) and that RMS; None if not finite."""
    nf = len(xf)
    rct = np.swapaxes(rf @ r_bc, 1, 2)[fr]  # (n, 3, 3) world(frame 0)-to-camera
    t = tf[fr][:, None]
    w = 1.0 / sig
    cov = np.eye(5)
    rms = math.inf
    for it in range(iters + 1):
        bb = _basis(g0 / gravity)
        c = v0 * t + 0.5 * g0 * t * t + cam_off[fr]
        x = (rct @ (xf[fc] - c)[..., None])[..., 0]
        zc = np.where(x[:, 2] > 1e-3, x[:, 2], 1e-3)
        zh = x[:, :2] / zc[:, None]
        r = (uv - zh) * w[:, None]  # (n, 2)
        jx = (rct[:, :2, :] - zh[:, :, None] * rct[:, 2:3, :]) * (w / zc)[:, None, None]
        jt = np.zeros((len(fr), 2, 5))
        jt[:, :, 0:3] = -jx * t[:, :, None]
        jt[:, :, 3:5] = -(jx @ bb) * (0.5 * t * t)[:, :, None]
        dof = max(2 * len(fr) - 5 - 3 * nf, 1)
        rms = math.sqrt(float((r * r).sum()) / dof)
        htt = np.einsum("nki,nkj->ij", jt, jt)
        bt = np.einsum("nki,nk->i", jt, r)
        hxx = np.zeros((nf, 3, 3))
        np.add.at(hxx, fc, np.einsum("nki,nkj->nij", jx, jx))
        hxx += 1e-9 * np.eye(3)
        htx = np.zeros((nf, 5, 3))
        np.add.at(htx, fc, np.einsum("nki,nkj->nij", jt, jx))
        bx = np.zeros((nf, 3))
        np.add.at(bx, fc, np.einsum("nki,nk->ni", jx, r))
        hinv = np.linalg.inv(hxx)
        m = htx @ hinv  # (nf, 5, 3)
        schur = htt - np.einsum("fij,fkj->ik", m, htx)
        cov = np.linalg.inv(schur)
        if it == iters:
            break
        dt = cov @ (bt - np.einsum("fij,fj->i", m, bx))
        dxf = (hinv @ (bx - np.einsum("fji,j->fi", htx, dt))[..., None])[..., 0]
        v0 = v0 + dt[0:3]
        g0 = g0 + bb @ dt[3:5]
        g0 = gravity * g0 / np.linalg.norm(g0)
        xf = xf + dxf
        if not (np.isfinite(v0).all() and np.isfinite(xf).all()):
            return None
    return v0, g0, xf, max(rms, 1.0) ** 2 * cov, rms
