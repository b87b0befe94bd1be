"""Seeded procedural textures: multi-scale noise, blobs, edges and corners.

A texture is an ``(n, n)`` ``uint8`` image, periodic (it tiles seamlessly: the noise octaves
are upsampled with wrap-around and shapes are drawn modulo the tile), made from::

    T = 0.5 + strength * (0.5 * N + 0.35 * S) / max|0.5 * N + 0.35 * S|   (clipped to [0, 1])

with ``N = sum_o 0.8^o U_o`` the octaves of uniform noise on grids of ``4 * 2^o`` cells
upsampled bicubically (smooth structure at every scale), and ``S`` in [-1, 1] the shapes:
filled discs (blobs), rectangles (corners) and lines (edges) of random grey levels.
``strength`` in [0, 1] scales the contrast about mid grey: 0 gives a uniform (featureless)
plane. Nothing is downloaded; the same ``seed`` gives the same bits.
"""

from __future__ import annotations

import cv2
import numpy as np


def _octaves(rng: np.random.Generator, n: int) -> np.ndarray:
    """``sum_o 0.8^o U_o``: each octave's grid padded by wrap-around, upsampled, cropped."""
    out = np.zeros((n, n), np.float32)
    cells, amp = 4, 1.0
    while cells <= n // 2:
        g = rng.uniform(-1.0, 1.0, (cells, cells)).astype(np.float32)
        pad = 2
        big = np.pad(g, pad, mode="wrap")
        scale = n // cells
        up = cv2.resize(
            big, ((cells + 2 * pad) * scale, (cells + 2 * pad) * scale),
            interpolation=cv2.INTER_CUBIC,
        )  # fmt: skip
        o = pad * scale
        out += amp * cv2.resize(up[o : o + cells * scale, o : o + cells * scale], (n, n))
        cells, amp = cells * 2, amp * 0.8
    return out


def _shapes(rng: np.random.Generator, n: int, count: int) -> np.ndarray:
    """Blobs, rectangles and lines in [-1, 1]; a shape near an edge is drawn again shifted
    by the tile's side, so the result is periodic."""
    canvas = np.zeros((n, n), np.float32)
    kinds = rng.integers(0, 3, count)
    levels = rng.uniform(-1.0, 1.0, count)
    centres = rng.integers(0, n, (count, 2))
    sizes = rng.integers(max(2, n // 200), max(3, n // 60), count)
    hs = rng.integers(2, 2 * sizes + 3)
    angs = rng.uniform(0.0, np.pi, count)
    for i in range(count):
        kind, level, size, h = int(kinds[i]), float(levels[i]), int(sizes[i]), int(hs[i])
        dx, dy = int(3 * size * np.cos(angs[i])), int(3 * size * np.sin(angs[i]))
        reach = 3 * size + h
        cx, cy = int(centres[i, 0]), int(centres[i, 1])
        xs = [0] + ([-n] if cx + reach >= n else []) + ([n] if cx - reach < 0 else [])
        ys = [0] + ([-n] if cy + reach >= n else []) + ([n] if cy - reach < 0 else [])
        for ox in xs:
            for oy in ys:
                x, y = cx + ox, cy + oy
                if kind == 0:
                    cv2.circle(canvas, (x, y), size, level, -1, cv2.LINE_AA)
                elif kind == 1:
                    cv2.rectangle(canvas, (x, y), (x + size, y + h), level, -1)
                else:
                    cv2.line(
                        canvas, (x, y), (x + dx, y + dy), level, max(1, size // 4), cv2.LINE_AA
                    )
    return canvas


def make_texture(
    seed: int, size: int, strength: float, shapes_per_mpx: float = 2500.0
) -> np.ndarray:
    """The texture of the module docstring, ``(size, size)`` uint8."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 25]))
    noise = _octaves(rng, size)
    count = int(shapes_per_mpx * size * size / 1e6)
    shape_rng = np.random.default_rng(np.random.SeedSequence([int(seed), 26]))
    shapes = _shapes(shape_rng, size, count)
    mix = 0.5 * noise + 0.35 * shapes
    mix /= max(float(np.abs(mix).max()), 1e-6)
    t = 0.5 + 0.5 * float(strength) * mix
    return np.clip(np.rint(t * 255.0), 0, 255).astype(np.uint8)
