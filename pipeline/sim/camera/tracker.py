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
_HALO = 5
"""Pixels around a free cell given to FAST (its circle's radius 3, plus non-maximum
suppression's neighbour, plus one)."""


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
        # pixel columns and rows of each grid cell (as _cells assigns integer pixels): FAST
        # runs on the free cells only
        self._col_edges = self._edges(cam.width, self.cell[0], self.cols)
        self._row_edges = self._edges(cam.height, self.cell[1], self.rows)

    @staticmethod
    def _edges(size: int, cell: float, n: int) -> np.ndarray:
        """``e`` (n + 1,) with the pixels ``e[i] <= x < e[i + 1]`` in cell ``i``."""
        of = np.minimum((np.arange(size, dtype=np.float32) / cell).astype(int), n - 1)
        return np.searchsorted(of, np.arange(n + 1), side="left")

    def _cells(self, pts: np.ndarray) -> np.ndarray:
        cx = np.minimum((pts[:, 0] / self.cell[0]).astype(int), self.cols - 1)
        cy = np.minimum((pts[:, 1] / self.cell[1]).astype(int), self.rows - 1)
        return cy * self.cols + cx

    def _corners(self, img: np.ndarray, taken: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """FAST corners (pixels (n, 2), responses (n,)) in the cells not ``taken``, at least
        :data:`_MARGIN` px inside the image: FAST runs on each free cell grown by
        :data:`_HALO` px (a corner's score reads a radius-3 circle and non-maximum
        suppression its neighbours' scores, so inside the cell the corners and scores are
        those of the whole image), cells in order, each in OpenCV's row-major order."""
        cam = self.cam
        ce, re = self._col_edges, self._row_edges
        xys, resps = [], []
        for c in np.flatnonzero(~taken).tolist():
            y, x = divmod(c, self.cols)
            x0, x1 = max(int(ce[x]), _MARGIN), min(int(ce[x + 1]), cam.width - _MARGIN)
            y0, y1 = max(int(re[y]), _MARGIN), min(int(re[y + 1]), cam.height - _MARGIN)
            if x1 <= x0 or y1 <= y0:
                continue
            gx, gy = max(x0 - _HALO, 0), max(y0 - _HALO, 0)
            kps = self.fast.detect(
                img[gy : min(y1 + _HALO, cam.height), gx : min(x1 + _HALO, cam.width)]
            )
            if not kps:
                continue
            xy = np.asarray(cv2.KeyPoint.convert(kps), np.float32).reshape(-1, 2)
            xy += np.array([gx, gy], np.float32)
            inside = (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)
            resp = np.fromiter((k.response for k in kps), np.float32, len(kps))
            xys.append(xy[inside])
            resps.append(resp[inside])
        if not xys:
            return np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
        return np.concatenate(xys), np.concatenate(resps)

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
        xy, resp = self._corners(img, taken)
        if not len(xy):
            return
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
