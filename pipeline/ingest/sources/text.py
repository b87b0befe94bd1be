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


# A text trajectory is written in time order; a stamp earlier than one before it by more
# than this is an error naming its line (re-sorting it silently made a 0.45 m error spike).
ORDER_TOLERANCE_NS = 100_000_000


def _rows(path: Path, sep: str | None) -> tuple[list[list[str]], list[int]]:
    """The data rows and their 1-based line numbers in the file."""
    rows, lines = [], []
    for k, line in enumerate(Path(path).read_text(errors="replace").splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#") or line[0].isalpha():
            continue
        rows.append([p.strip() for p in (line.split(sep) if sep else line.split())])
        lines.append(k)
    return rows, lines


def check_order(path: Path, ns: np.ndarray, lines: list[int]) -> None:
    """Refuse a stamp more than :data:`ORDER_TOLERANCE_NS` earlier than the latest before it."""
    if len(ns) < 2:
        return
    back = np.maximum.accumulate(ns)[:-1] - ns[1:]
    bad = np.flatnonzero(back > ORDER_TOLERANCE_NS)
    if len(bad):
        k = int(bad[0]) + 1
        raise InputError(
            f"{path}: line {lines[k]}: stamp {ns[k] * 1e-9:.9g} s is {back[k - 1] * 1e-9:.3g} s "
            f"earlier than a line before it (tolerance {ORDER_TOLERANCE_NS * 1e-9:g} s; "
            f"{len(bad)} such lines); a trajectory file must be in time order: fix or sort it"
        )


def read_tum(path: Path) -> Trajectory:
    rows, lines = _rows(path, None)
    bad = [i for i, r in enumerate(rows) if len(r) != 8]
    if bad:
        raise InputError(
            f"{path}: line {lines[bad[0]]} has {len(rows[bad[0]])} fields; TUM needs 8 "
            "('t x y z qx qy qz qw')"
        )
    try:
        a = np.array(rows, dtype=float).reshape(-1, 8)
        # stamps from the text itself: seconds with up to 9 decimals, exactly in ns
        ns = np.array([_sec_to_ns(r[0]) for r in rows], dtype=np.int64)
    except ValueError as exc:
        raise InputError(f"{path}: a value is not a number ({exc})") from None
    check_order(path, ns, lines)
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
    rows, lines = _rows(path, ",")
    bad = [i for i, r in enumerate(rows) if len(r) < 8]
    if bad:
        raise InputError(
            f"{path}: line {lines[bad[0]]} has {len(rows[bad[0]])} fields; the EuRoC csv "
            "needs at least 8 ('t_ns, px, py, pz, qw, qx, qy, qz')"
        )
    width = min(len(r) for r in rows)
    try:
        ns = np.array([int(r[0]) for r in rows], dtype=np.int64)
        a = np.array([r[:width] for r in rows], dtype=float)
    except ValueError as exc:
        raise InputError(f"{path}: a value is not a number ({exc})") from None
    check_order(path, ns, lines)
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
