"""Text trajectories as evo reads them: TUM files and the EuRoC ground-truth csv.

- TUM: one pose per line, ``t x y z qx qy qz qw``, ``t`` in seconds, ``#`` comments.
- EuRoC csv (``state_groundtruth_estimate0/data.csv``): ``t_ns, p(3), q(w, x, y, z),
  v(3) world frame, gyro bias(3), accel bias(3)``; a ``#timestamp`` header line. Its
  velocity is the dataset's own (world frame), kept in ``Trajectory.velocity``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.ingest.sources.base import Trajectory

TUM = "text/tum"
EUROC = "text/euroc-csv"


def _rows(path: Path, sep: str | None) -> list[list[str]]:
    rows = []
    for line in Path(path).read_text(errors="replace").splitlines():
        line = line.strip()
        if not line or line.startswith("#") or line[0].isalpha():
            continue
        rows.append([p.strip() for p in (line.split(sep) if sep else line.split())])
    return rows


def read_tum(path: Path) -> Trajectory:
    rows = _rows(path, None)
    bad = [i for i, r in enumerate(rows) if len(r) != 8]
    if bad:
        raise InputError(
            f"{path}: data line {bad[0] + 1} has {len(rows[bad[0]])} fields; TUM needs 8 "
            "('t x y z qx qy qz qw')"
        )
    try:
        a = np.array(rows, dtype=float).reshape(-1, 8)
        # stamps from the text itself: seconds with up to 9 decimals, exactly in ns
        ns = np.array([_sec_to_ns(r[0]) for r in rows], dtype=np.int64)
    except ValueError as exc:
        raise InputError(f"{path}: a value is not a number ({exc})") from None
    return Trajectory(
        name=Path(path).name,
        msgtype=TUM,
        header_ns=ns,
        log_ns=ns.copy(),
        position=a[:, 1:4],
        orientation=a[:, 4:8],
        velocity=None,
        decoder="text",
    )


def _sec_to_ns(s: str) -> int:
    if "e" in s.lower():
        return round(float(s) * 1e9)
    neg = s.startswith("-")
    whole, _, frac = s.lstrip("+-").partition(".")
    ns = int(whole or "0") * 1_000_000_000 + int((frac + "000000000")[:9])
    return -ns if neg else ns


def read_euroc(path: Path) -> Trajectory:
    rows = _rows(path, ",")
    bad = [i for i, r in enumerate(rows) if len(r) < 8]
    if bad:
        raise InputError(
            f"{path}: data line {bad[0] + 1} has {len(rows[bad[0]])} fields; the EuRoC csv "
            "needs at least 8 ('t_ns, px, py, pz, qw, qx, qy, qz')"
        )
    width = min(len(r) for r in rows)
    try:
        ns = np.array([int(r[0]) for r in rows], dtype=np.int64)
        a = np.array([r[:width] for r in rows], dtype=float)
    except ValueError as exc:
        raise InputError(f"{path}: a value is not a number ({exc})") from None
    return Trajectory(
        name=Path(path).name,
        msgtype=EUROC,
        header_ns=ns,
        log_ns=ns.copy(),
        position=a[:, 1:4],
        orientation=a[:, [5, 6, 7, 4]],
        velocity=a[:, 8:11] if width >= 11 else None,
        decoder="text",
    )
