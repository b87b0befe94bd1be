"""Image formation: the textured planes seen through the exposure, with noise and clipping.

**Exposure.** Auto exposure in light level ``L`` in (0, 1]: ``t = min(t0 / L, t_max)``; a
white texel collects ``E = E_full L t / t0`` electrons (``E_full`` at ``t0`` in full light),
and the gain ``g = 255 / E`` (DN per electron) brings white back to 255. So less light means
a longer exposure (more blur) and, once ``t`` reaches ``t_max``, fewer electrons and a higher
gain (more noise).

**Motion blur.** The frame is stamped at the middle of its exposure. ``N`` sub-frames at
``tau_j = t + t_exp ((j + 1/2) / N - 1/2)`` are rendered from the pose moved by the true body
rate and velocity, ``R(tau) = R(t) exp(omega (tau - t))``, ``p(tau) = p(t) + v (tau - t)``,
and averaged (the integral of the irradiance over the exposure by the midpoint rule). ``N =
clip(ceil(b / b_s), 1, N_max)`` with ``b = t_exp f (||omega|| + ||v|| / d)`` the image motion in
pixels over the exposure (``d``: distance to the ground along the optical axis) and ``b_s``
pixels of motion per sub-frame.

**Noise.** Albedo ``rho`` in [0, 1] (the averaged sub-frames), electrons ``e = rho E``, shot
noise (Poisson, as a Gaussian of variance ``e``) and read noise ``sigma_r``::

    DN = clip(round(255 rho + g sqrt(e + sigma_r^2) z), 0, 255),    z ~ N(0, 1)

``z`` is cut from one seeded standard-normal field of twice the image's size at a random
offset per frame (a fresh ``N(0, 1)`` per pixel within a frame, at a fraction of the cost of
drawing 90 000 normals per frame). A lens cap (``dark``) makes ``rho = 0``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from qsls.pipeline.sim.camera.geometry import so3_exp
from qsls.pipeline.sim.camera.options import CameraOptions
from qsls.pipeline.sim.camera.world import Plane, intrinsics

HAZE = 0.6
"""Albedo of the featureless haze beyond the planes' range (and of the sky)."""


def exposure(cam: CameraOptions, light: float) -> tuple[float, float]:
    """``(t_exp, E)``: exposure time (s) and a white texel's electrons (module docstring)."""
    t = min(cam.exposure_s / light, cam.exposure_max_s)
    return t, cam.full_well_e * light * t / cam.exposure_s


class Renderer:
    """Renders frames of one flight: planes, exposure, blur, noise (module docstring)."""

    def __init__(
        self,
        cam: CameraOptions,
        planes: list[Plane],
        light: float,
        seed_seq: np.random.SeedSequence,
    ) -> None:
        self.cam = cam
        self.planes = planes
        self.k = intrinsics(cam)
        self.k_inv = np.linalg.inv(self.k)
        self.size = (cam.width, cam.height)
        self.t_exp, self.electrons = exposure(cam, light)
        self.gain = 255.0 / self.electrons
        self.rng = np.random.default_rng(seed_seq)
        h, w = cam.height, cam.width
        self._field = self.rng.standard_normal((2 * h, 2 * w), dtype=np.float32)
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
        self._pix = (xs, ys)
        levels = np.arange(256, dtype=np.float32)
        self._sigma_lut = (
            (np.sqrt(levels * (self.electrons / 255.0) + cam.read_noise_e**2) * self.gain)
            .astype(np.float32)
            .reshape(1, 256)
        )
        self.last_blur_px = 0.0

    # ------------------------------------------------------------------ geometry
    def visible_fraction(self, r_wc: np.ndarray, p: np.ndarray) -> float:
        """Fraction of the image that sees a textured plane (no blur, no noise)."""
        cov = np.zeros((self.cam.height, self.cam.width), np.uint8)
        for pl in self.planes:
            cov |= self._mask(pl, r_wc, p) > 0
        return float(cov.mean())

    def _mask(self, pl: Plane, r_wc: np.ndarray, p: np.ndarray) -> np.ndarray:
        """255 where the pixel sees ``pl`` (in front, in range, within a wall's extent)."""
        line = pl.front_line(self.k_inv, r_wc, p)
        xs, ys = self._pix
        mask = ((line[0] * xs + line[1] * ys + line[2]) > 0).astype(np.uint8) * 255
        if not pl.tiled:
            h = pl.tex_to_image(self.k, r_wc.T, p)
            ones = np.full((pl.extent_px[1], pl.extent_px[0]), 255, np.uint8)
            inside = cv2.warpPerspective(
                ones, np.linalg.inv(h), self.size,
                flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
            )  # fmt: skip
            mask &= inside
        return mask

    def _corners_visible(self, pl: Plane, r_wc: np.ndarray, p: np.ndarray) -> bool:
        line = pl.front_line(self.k_inv, r_wc, p)
        w, h = self.cam.width - 1, self.cam.height - 1
        return all(
            line[0] * x + line[1] * y + line[2] > 0 for x, y in ((0, 0), (w, 0), (0, h), (w, h))
        )

    def albedo(self, r_wc: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Albedo in [0, 255] of one instant (the planes over the haze): uint8 when the
        ground fills the image, else float32."""
        out: np.ndarray | None = None
        for pl in self.planes:
            h_inv = np.linalg.inv(pl.tex_to_image(self.k, r_wc.T, p))
            img = cv2.warpPerspective(
                pl.texture, h_inv, self.size,
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_REFLECT_101 if pl.tiled else cv2.BORDER_CONSTANT,
            )  # fmt: skip
            full = pl.tiled and self._corners_visible(pl, r_wc, p)
            if out is None:
                if full and len(self.planes) == 1:
                    return img  # uint8: the usual case, one fully visible ground
                if full:
                    out = img.astype(np.float32)
                    continue
                out = np.full((self.cam.height, self.cam.width), HAZE * 255.0, np.float32)
            if full:
                out[:] = img
            else:
                mask = self._mask(pl, r_wc, p)
                if mask.any():
                    cv2.copyTo(img.astype(np.float32), mask, out)
        assert out is not None
        return out

    # ------------------------------------------------------------------ a frame
    def blur_pixels(
        self, r_wc: np.ndarray, p: np.ndarray, omega: np.ndarray, v: np.ndarray
    ) -> float:
        """``b`` of the module docstring (px over the exposure)."""
        axis = r_wc[:, 2]
        ground = self.planes[0]
        cos = -float(axis @ ground.normal)
        height = float(ground.normal @ (p - ground.origin))
        depth = height / cos if cos > 0.05 and height > 0 else MAX_DEPTH_FALLBACK
        depth = max(depth, 0.2)
        rate = math.sqrt(float(omega @ omega)) + math.sqrt(float(v @ v)) / depth
        return self.t_exp * self.cam.focal_px * rate

    def render(
        self, r_wb: np.ndarray, p_wb: np.ndarray, omega: np.ndarray, v: np.ndarray,
        r_bc: np.ndarray, t_bc: np.ndarray, *, dark: bool = False,
    ) -> np.ndarray:  # fmt: skip
        """The uint8 frame seen from body pose ``(r_wb, p_wb)`` moving at body rate ``omega``
        and world velocity ``v``; camera mount ``(r_bc, t_bc)``."""
        cam = self.cam
        r_wc = r_wb @ r_bc
        p_wc = p_wb + r_wb @ t_bc
        b = self.blur_pixels(r_wc, p_wc, r_wb @ omega, v)
        n = (
            1
            if dark
            else max(1, min(cam.blur_max_substeps, math.ceil(b / cam.blur_px_per_substep)))
        )
        self.last_blur_px = b
        if dark:
            rho = np.zeros((cam.height, cam.width), np.float32)
        elif n == 1:
            rho = self.albedo(r_wc, p_wc)
        else:
            rho = np.zeros((cam.height, cam.width), np.float32)
            for j in range(n):
                dt = self.t_exp * ((j + 0.5) / n - 0.5)
                rb = r_wb @ so3_exp(omega * dt)
                pb = p_wb + v * dt
                cv2.add(rho, self.albedo(rb @ r_bc, pb + rb @ t_bc), dst=rho, dtype=cv2.CV_32F)
            rho *= 1.0 / n
        return self.expose(rho)

    def expose(self, rho255: np.ndarray) -> np.ndarray:
        """Noise, rounding and clipping of an albedo image in [0, 255] (module docstring);
        ``rho255`` uint8 (one sub-frame: the noise's std from a table) or float32."""
        cam = self.cam
        if not cam.noise:
            if rho255.dtype == np.uint8:
                return rho255
            return cv2.add(rho255, np.zeros_like(rho255), dtype=cv2.CV_8U)
        if rho255.dtype == np.uint8:
            sigma = cv2.LUT(rho255, self._sigma_lut)
        else:
            sigma = cv2.sqrt(rho255 * (self.electrons / 255.0) + cam.read_noise_e**2) * self.gain
        oy = int(self.rng.integers(0, cam.height))
        ox = int(self.rng.integers(0, cam.width))
        z = self._field[oy : oy + cam.height, ox : ox + cam.width]
        # cv2.add with an 8-bit result rounds to nearest and saturates to [0, 255]
        return cv2.add(rho255, cv2.multiply(sigma, z), dtype=cv2.CV_8U)


MAX_DEPTH_FALLBACK = 5.0
"""Depth (m) assumed for the translational blur when the optical axis misses the ground."""
