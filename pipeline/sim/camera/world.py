"""The textured world: planes, each drawn through its homography.

A plane has an origin ``o``, two orthonormal in-plane axes ``a1, a2`` (its normal ``n = a1 x
a2`` faces the viewer) and a texture of ``m`` metres per texel. The world point of texel
``(u, v)`` is ``X = o + m u a1 + m v a2``; a camera at ``p`` with world-to-camera rotation
``R_cw`` and intrinsics ``K`` sees it at pixel ``~ K R_cw (X - p)``, so::

    H_tex->img = K R_cw [m a1 | m a2 | o - p]

and ``cv2.warpPerspective`` with ``H_img->tex = H_tex->img^-1`` renders the plane. A pixel
sees the plane in front of the camera when its ray ``d = R_wc K^-1 [x, y, 1]`` satisfies
``(n . d) (n . (o - p)) > 0``; with a range limit ``r_max`` (beyond it: featureless haze)
the condition ``-(n . d) > |n . (o - p)| / r_max`` is linear in the pixel, so the visible
part of a plane is a half-plane of the image (a wall is further clipped to its extent).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from qsls.pipeline.sim.camera.options import CameraOptions, TexturePath
from qsls.pipeline.sim.camera.texture import make_texture

MAX_RANGE_M = 12.0
"""Farther than this a plane fades into a uniform haze (no texture to track)."""


@dataclass(frozen=True)
class Plane:
    origin: np.ndarray  # (3,)
    a1: np.ndarray  # (3,) unit, texture u axis
    a2: np.ndarray  # (3,) unit, texture v axis
    m_per_px: float
    texture: np.ndarray  # (n, n) uint8
    tiled: bool  # the ground extends its tile (mirrored); a wall ends at its texture's edges
    extent_px: tuple[int, int]  # (u, v) texels of a finite plane

    @cached_property
    def normal(self) -> np.ndarray:
        return np.cross(self.a1, self.a2)

    def tex_to_image(self, k: np.ndarray, r_cw: np.ndarray, p: np.ndarray) -> np.ndarray:
        """``H_tex->img`` of the module docstring."""
        m = self.m_per_px
        return k @ r_cw @ np.column_stack([m * self.a1, m * self.a2, self.origin - p])

    def front_line(self, k_inv: np.ndarray, r_wc: np.ndarray, p: np.ndarray) -> np.ndarray:
        """``l`` (3,) with ``l . [x, y, 1] > 0`` exactly where pixel ``(x, y)`` sees the plane
        in front of the camera within :data:`MAX_RANGE_M` (module docstring)."""
        n = self.normal
        dist = float(n @ (self.origin - p))
        side = -1.0 if dist < 0 else 1.0
        # side * (n . d) > |dist| / r_max with d = R_wc K^-1 [x, y, 1]
        row = side * (n @ r_wc @ k_inv)
        row[2] -= abs(dist) / MAX_RANGE_M
        return row


def intrinsics(cam: CameraOptions) -> np.ndarray:
    """``K`` of the undistorted pinhole (principal point at the image centre)."""
    return np.array(
        [
            [cam.focal_px, 0.0, (cam.width - 1) / 2.0],
            [0.0, cam.focal_px, (cam.height - 1) / 2.0],
            [0.0, 0.0, 1.0],
        ]
    )


_TEXTURES: dict[tuple[int, int], np.ndarray] = {}


def _base_texture(seed: int, size: int) -> np.ndarray:
    """Full-contrast texture, made once per process (0.2 s for 1600 texels)."""
    key = (seed, size)
    if key not in _TEXTURES:
        _TEXTURES[key] = make_texture(seed, size, 1.0)
    return _TEXTURES[key]


def scaled(texture: np.ndarray, strength: float) -> np.ndarray:
    """``128 + strength (T - 128)``: the texture's contrast times ``strength``."""
    if strength == 1.0:
        return texture
    t = 128.0 + float(strength) * (texture.astype(np.float32) - 128.0)
    return np.clip(np.rint(t), 0, 255).astype(np.uint8)


def path_contrast(tp: TexturePath, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The contrast factor of :class:`TexturePath` at ground points ``(x, y)``: with ``d``
    the distance to the circle and ``c`` to its centre, ``g = level + (1 - level) max(ramp(d
    - band), ramp(c - pad))``, ``ramp(s) = clip(1 - s / ramp_m, 0, 1)``."""
    c = np.hypot(x - tp.centre[0], y - tp.centre[1])
    d = np.abs(c - tp.radius)

    def ramp(s: np.ndarray) -> np.ndarray:
        return np.clip(1.0 - s / tp.ramp_m, 0.0, 1.0)

    return tp.level + (1.0 - tp.level) * np.maximum(ramp(d - tp.band_m), ramp(c - tp.pad_m))


def regional(texture: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """``128 + factor (T - 128)`` texel by texel (:func:`scaled` with a contrast map)."""
    t = 128.0 + factor.astype(np.float32) * (texture.astype(np.float32) - 128.0)
    return np.clip(np.rint(t), 0, 255).astype(np.uint8)


def build_world(cam: CameraOptions, texture_level: float) -> list[Plane]:
    """The ground (tiled) and the walls of ``cam``, texture contrast ``cam.texture_strength
    * texture_level`` (on the ground times :func:`path_contrast` with ``cam.texture_path``);
    the ground first, the walls after (a wall stands on the ground and hides what is behind
    it)."""
    n = max(16, round(cam.texture_size_m / cam.texture_m_per_px))
    strength = cam.texture_strength * texture_level
    ground_tex = scaled(_base_texture(cam.texture_seed, n), strength)
    if cam.texture_path is not None:
        # texel (u, v) lies at (x0 + m u, y0 + m v): columns along x, rows along y
        axis = -0.5 * n * cam.texture_m_per_px + cam.texture_m_per_px * np.arange(n)
        factor = path_contrast(cam.texture_path, axis[None, :], axis[:, None])
        ground_tex = regional(_base_texture(cam.texture_seed, n), strength * factor)
    planes = [
        Plane(
            # the tile centred on the origin (flights stay well inside; beyond, it mirrors)
            origin=np.array(
                [-0.5 * n * cam.texture_m_per_px, -0.5 * n * cam.texture_m_per_px, cam.ground_z]
            ),
            a1=np.array([1.0, 0.0, 0.0]),
            a2=np.array([0.0, 1.0, 0.0]),
            m_per_px=cam.texture_m_per_px,
            texture=ground_tex,
            tiled=True,
            extent_px=(n, n),
        )
    ]
    for i, w in enumerate(cam.walls):
        start = np.array([w.start[0], w.start[1], w.top])
        end = np.array([w.end[0], w.end[1], w.top])
        a1 = end - start
        length = float(np.linalg.norm(a1))
        a1 /= length
        a2 = np.array([0.0, 0.0, -1.0])
        nu = max(2, round(length / cam.texture_m_per_px))
        nv = max(2, round((w.top - w.bottom) / cam.texture_m_per_px))
        base = _base_texture(cam.texture_seed + 1000 + i, max(nu, nv))
        planes.append(
            Plane(
                origin=start,
                a1=a1,
                a2=a2,
                m_per_px=cam.texture_m_per_px,
                texture=scaled(np.ascontiguousarray(base[:nv, :nu]), strength),
                tiled=False,
                extent_px=(nu, nv),
            )
        )
    return planes
