"""Write a TUM trajectory: ``t x y z qx qy qz qw`` per line, ``t`` in seconds with nine
decimals (exact nanoseconds, read back so by :func:`.reader.read_tum`), values with nine.
docs/ingest.md#formats."""

from __future__ import annotations

import numpy as np

TUM_HEADER = "# timestamp tx ty tz qx qy qz qw (VIO clock, truth frame; written by qsls ingest)"


def tum_text(t_ns: np.ndarray, p: np.ndarray, q: np.ndarray, header: str = TUM_HEADER) -> str:
    """The TUM text of stamps ``t_ns`` (int64 ns), positions ``p`` (n, 3) and quaternions
    ``q`` (n, 4, ``x y z w``), under one ``#`` comment line."""
    lines = [header]
    for k in range(len(t_ns)):
        sec, ns = divmod(int(t_ns[k]), 1_000_000_000)
        vals = " ".join(f"{x:.9f}" for x in (*p[k], *q[k]))
        lines.append(f"{sec}.{ns:09d} {vals}")
    return "\n".join(lines) + "\n"
