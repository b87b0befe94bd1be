"""Text trajectories as evo reads them: TUM files and the EuRoC ground-truth csv.

- TUM: one pose per line, ``t x y z qx qy qz qw``, ``t`` in seconds, ``#`` comments.
  Stamps written as integer nanoseconds (a ROS-exported TUM file) are recognized by their
  size (:func:`tum_stamps_ns`) and read as nanoseconds.
- EuRoC csv (``state_groundtruth_estimate0/data.csv``): ``t_ns, p(3), q(w, x, y, z),
  v(3) world frame, gyro bias(3), accel bias(3)``; a ``#timestamp`` header line. Its
  velocity is the dataset's own (world frame), kept in ``Trajectory.velocity``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.ingest.sources.base import Trajectory
from qsls.pipeline.ingest.sources.msgtypes import EUROC, TUM

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
    except ValueError as exc:
        raise InputError(f"{path}: a value is not a number ({exc})") from None
    ns = tum_stamps_ns(path, [r[0] for r in rows], lines)
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


NS_STAMP_MIN = 10**15
"""An integer TUM stamp at least this large is nanoseconds: as seconds it would be 31
million years; as nanoseconds it is 11.6 days after the clock's zero (ROS time since 1970
is 1.7e18 ns)."""


def tum_stamps_ns(path: Path, stamps: list[str], lines: list[int]) -> np.ndarray:
    """TUM stamps as int64 nanoseconds: seconds (up to 9 decimals, exact), or integer
    nanoseconds when every stamp is an integer and the first is at least
    :data:`NS_STAMP_MIN`."""
    if all(s.lstrip("+-").isdigit() for s in stamps) and int(stamps[0]) >= NS_STAMP_MIN:
        out = [int(s) for s in stamps]
        unit = "nanoseconds"
    else:
        try:
            out = [_sec_to_ns(s) for s in stamps]
        except ValueError:
            bad = next(i for i, s in enumerate(stamps) if not _is_number(s))
            raise InputError(
                f"{path}: line {lines[bad]}: stamp '{stamps[bad]}' is not a number"
            ) from None
        unit = "seconds"
    limit = np.iinfo(np.int64).max
    big = next((i for i, v in enumerate(out) if abs(v) > limit), None)
    if big is not None:
        raise InputError(
            f"{path}: line {lines[big]}: stamp {stamps[big]} read as {unit} is beyond any clock; "
            "TUM stamps are seconds ('1403636579.758555'), or integer nanoseconds "
            f"(>= {NS_STAMP_MIN:.0e})"
        )
    return np.array(out, dtype=np.int64)


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


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
    odd = next((i for i, r in enumerate(rows) if not r[0].lstrip("+-").isdigit()), None)
    if odd is not None:
        what = (
            f"{len(rows[odd])} comma-separated fields with a stamp in seconds: a TUM file with "
            "commas? TUM separates 't x y z qx qy qz qw' (t in seconds) by spaces; replace the "
            "commas by spaces"
            if len(rows[odd]) == 8 and _is_number(rows[odd][0])
            else "a stamp that is not an integer"
        )
        raise InputError(
            f"{path}: read as EuRoC csv (comma-separated, 't_ns, px, py, pz, qw, qx, qy, qz, "
            f"...' with t in integer nanoseconds), but line {lines[odd]} has "
            f"'{rows[odd][0]}', {what}"
        )
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


TEXT_READERS: dict[str, Callable[[Path], Trajectory]] = {"tum": read_tum, "euroc": read_euroc}
"""The text kinds :func:`~qsls.pipeline.ingest.sources.base.detect` finds to their readers."""
