"""Feature tracking: FAST corners, pyramidal KLT, RANSAC on the epipolar constraint.

Per frame: the previous frame's features are tracked by Lucas-Kanade optical flow on image
pyramids (``cv2.calcOpticalFlowPyrLK``); tracks that fail, leave the image, or violate the
epipolar constraint ``x2^T F x1 = 0`` of a RANSAC fundamental matrix (``cv2.findFundamentalMat``,
threshold in pixels) end. Then new FAST corners (``cv2.FastFeatureDetector``) fill the free
cells of a ``cols x rows`` grid, the strongest corner per free cell (at most one feature per
cell keeps them spread over the image), up to ``max_features``.

Output per frame: ids (int64) and pixel positions (float32, (n, 2)) of the features seen.
"""

from __future__ import annotations

import cv2
import numpy as np

from qsls.pipeline.sim.camera.options import CameraOptions

_MIN_RANSAC = 12
_MARGIN = 4
"""New features start at least this many pixels inside the image."""


class Tracker:
    """Tracks features frame to frame (module docstring)."""

    def __init__(self, cam: CameraOptions) -> None:
        self.cam = cam
        self.fast = cv2.FastFeatureDetector.create(cam.fast_threshold, True)
        self.win = (cam.klt_window, cam.klt_window)
        self.criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03)
        self.cols, self.rows = cam.grid
        self.cell = (cam.width / self.cols, cam.height / self.rows)
        self.prev: np.ndarray | None = None
        self.pts = np.zeros((0, 2), np.float32)
        self.ids = np.zeros(0, np.int64)
        self.next_id = 0
        self.rejected = 0
        # pixel rows and columns of each grid cell (as _cells assigns integer pixels), and the
        # detection mask's margin: FAST runs on the free cells only
        self._col_edges = self._edges(cam.width, self.cell[0], self.cols)
        self._row_edges = self._edges(cam.height, self.cell[1], self.rows)
        self._mask = np.zeros((cam.height, cam.width), np.uint8)

    @staticmethod
    def _edges(size: int, cell: float, n: int) -> np.ndarray:
        """``e`` (n + 1,) with the pixels ``e[i] <= x < e[i + 1]`` in cell ``i``."""
        of = np.minimum((np.arange(size, dtype=np.float32) / cell).astype(int), n - 1)
        return np.searchsorted(of, np.arange(n + 1), side="left")

    def _cells(self, pts: np.ndarray) -> np.ndarray:
        cx = np.minimum((pts[:, 0] / self.cell[0]).astype(int), self.cols - 1)
        cy = np.minimum((pts[:, 1] / self.cell[1]).astype(int), self.rows - 1)
        return cy * self.cols + cx

    def _free_mask(self, taken: np.ndarray) -> np.ndarray:
        """255 on the pixels of the cells not ``taken`` at least 4 px inside the image (where
        a new feature may start), else 0. OpenCV's FAST filters its corners by the mask after
        detecting on the whole image, so the corners kept are those it finds unmasked; the
        mask only spares converting the others."""
        mask = self._mask
        mask[:] = 0
        ce, re = self._col_edges, self._row_edges
        for c in np.flatnonzero(~taken).tolist():
            y, x = divmod(c, self.cols)
            mask[re[y] : re[y + 1], ce[x] : ce[x + 1]] = 255
        m = _MARGIN
        mask[:m], mask[-m:], mask[:, :m], mask[:, -m:] = 0, 0, 0, 0
        return mask

    def track(self, img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ids and pixel positions of the features in ``img`` (module docstring)."""
        cam = self.cam
        if self.prev is not None and len(self.pts):
            nxt, st, _ = cv2.calcOpticalFlowPyrLK(
                self.prev, img, self.pts.reshape(-1, 1, 2), np.empty(0, np.float32),
                winSize=self.win, maxLevel=cam.klt_levels, criteria=self.criteria,
            )  # fmt: skip
            nxt = np.asarray(nxt)
            st = np.asarray(st)
            nxt = nxt.reshape(-1, 2)
            margin = 2.0
            ok = (
                (st.ravel() == 1)
                & (nxt[:, 0] >= margin) & (nxt[:, 0] <= cam.width - 1 - margin)
                & (nxt[:, 1] >= margin) & (nxt[:, 1] <= cam.height - 1 - margin)
            )  # fmt: skip
            if ok.sum() >= _MIN_RANSAC:
                _, inl = cv2.findFundamentalMat(
                    self.pts[ok], nxt[ok], cv2.FM_RANSAC, cam.ransac_px, 0.99
                )
                if inl is not None:
                    idx = np.nonzero(ok)[0]
                    bad = idx[inl.ravel() == 0]
                    self.rejected += len(bad)
                    ok[bad] = False
            self.pts, self.ids = nxt[ok], self.ids[ok]
        self._detect(img)
        self.prev = img
        return self.ids.copy(), self.pts.copy()

    def _detect(self, img: np.ndarray) -> None:
        cam = self.cam
        free = cam.max_features - len(self.pts)
        if free < max(1, cam.max_features // 10):  # detect when a tenth is missing
            return
        taken = np.zeros(self.cols * self.rows, bool)
        taken[self._cells(self.pts)] = True
        kps = self.fast.detect(img, self._free_mask(taken))
        if not kps:
            return
        xy = np.asarray(cv2.KeyPoint.convert(kps), np.float32).reshape(-1, 2)
        resp = np.fromiter((k.response for k in kps), np.float32, len(kps))
        cell = self._cells(xy)
        order = np.lexsort((-resp, cell))  # by cell, strongest first
        first = np.ones(len(order), bool)
        first[1:] = cell[order][1:] != cell[order][:-1]
        best = order[first]
        best = best[~taken[cell[best]]]
        best = best[np.argsort(-resp[best], kind="stable")][:free]
        new = xy[best]
        self.pts = np.vstack([self.pts, new]).astype(np.float32)
        self.ids = np.concatenate([self.ids, np.arange(self.next_id, self.next_id + len(new))])
        self.next_id += len(new)
