"""The feature measurement noise from the image formation: per feature and frame.

Lucas-Kanade tracking aligns a window of ``N`` pixels between two frames; with image noise of
std ``s`` (DN) on both, its position error has the Cramer-Rao covariance ``2 s^2 G^-1``, ``G =
sum_window grad I grad I^T`` (the structure tensor). So the std along the worst direction is::

    sigma_px^2 = sigma_0^2 + k^2 2 s^2 / lambda_min(G)

``lambda_min(G)`` is measured on the frame itself (Sobel gradients in DN per pixel, summed
over the KLT window, less the noise's own share ``0.1875 s^2 N``: the Sobel kernel's squared
weights over 64): blur and weak texture lower it, so both raise ``sigma_px``. ``s`` comes from
the camera's own settings, as a real camera reports them: the gain ``g = 255 / E`` (DN per
electron, ``E`` a white pixel's electrons at the chosen exposure) and the read noise, at the
frame's mean level ``I``: ``s^2 = g I + (g sigma_r)^2`` (shot noise and read noise). ``k``
absorbs what the bound leaves out (the pyramid's approximations, the drift of a track that
is re-aligned frame to frame); ``sigma_0`` the floor (interpolation and quantization).
Nothing in it reads the true motion or the world's texture level.
"""

from __future__ import annotations

import cv2
import numpy as np

from qsls.pipeline.sim.camera.options import CameraOptions

SOBEL_NOISE = 12.0 / 64.0
"""Sum of the squared weights of the 3x3 Sobel derivative scaled by 1/8 (DN per pixel)."""


def structure_min_eig(img: np.ndarray, pts: np.ndarray, window: int) -> np.ndarray:
    """``lambda_min`` (n,) of the structure tensor summed over the ``window`` x ``window``
    pixels around each point ``pts`` (n, 2) (module docstring). Only the features' patches
    are differentiated: they are cut from the image (reflected beyond its border) and
    stacked into one column image for ``cv2.Sobel``; each patch keeps a one-pixel rim so that
    its inner ``window`` x ``window`` gradients are those of the whole image."""
    n = len(pts)
    if not n:
        return np.zeros(0)
    r = window // 2 + 1
    size = 2 * r + 1  # the window and its rim
    pad = cv2.copyMakeBorder(img, r, r, r, r, cv2.BORDER_REFLECT_101)
    h, w = img.shape
    x = np.clip(np.rint(pts[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.rint(pts[:, 1]).astype(int), 0, h - 1)
    off = np.arange(size)
    patches = pad[(y[:, None] + off)[:, :, None], (x[:, None] + off)[:, None, :]]
    col = np.ascontiguousarray(patches.reshape(n * size, size))
    gx = cv2.Sobel(col, cv2.CV_32F, 1, 0, ksize=3, scale=0.125).reshape(n, size, size)
    gy = cv2.Sobel(col, cv2.CV_32F, 0, 1, ksize=3, scale=0.125).reshape(n, size, size)
    lo, hi = r - window // 2, r + window // 2 + 1
    gx, gy = gx[:, lo:hi, lo:hi].astype(float), gy[:, lo:hi, lo:hi].astype(float)
    a = np.einsum("nij,nij->n", gx, gx)
    c = np.einsum("nij,nij->n", gy, gy)
    b = np.einsum("nij,nij->n", gx, gy)
    return 0.5 * ((a + c) - np.sqrt((a - c) ** 2 + 4.0 * b * b))


def pixel_sigma(
    cam: CameraOptions, img: np.ndarray, pts: np.ndarray, electrons: float
) -> np.ndarray:
    """``sigma_px`` (n,) of the features at ``pts`` (n, 2) in ``img`` (module docstring);
    ``electrons``: a white pixel's electrons at the camera's exposure."""
    gain = 255.0 / electrons
    level = float(cv2.mean(img)[0])
    s2 = gain * level + (gain * cam.read_noise_e) ** 2
    n = cam.klt_window * cam.klt_window
    lam = structure_min_eig(img, pts, cam.klt_window) - SOBEL_NOISE * s2 * n
    lam = np.maximum(lam, 1e-6 * n)
    sig = np.sqrt(cam.pixel_sigma_floor**2 + cam.pixel_noise_scale**2 * 2.0 * s2 / lam)
    return np.minimum(sig, cam.pixel_sigma_max)
