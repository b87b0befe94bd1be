"""The benchmarks' smoke mode: ``python benchmarks/SCRIPT.py --smoke``.

Every script in ``benchmarks/`` times qsls against its naive baseline in the same run. With
``--smoke`` it runs the same code path at the smallest sizes that still exercise it (a few
hundred messages, a small T, one repeat, one or two flights of a few seconds, a tiny grid):
it still computes both ways and checks what it checks (the same optimum, identical tables,
the same trajectory to the bit), prints its figures, writes only into a temporary folder,
and exits 0; a failed check exits non-zero. ``tests/test_benchmarks.py`` runs every script
so, which keeps them running as the library changes. A smoke run's times say nothing about
speed.
"""

from __future__ import annotations

import argparse
import atexit
import shutil
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

FLAG = "--smoke"
HELP = "the same code path at the smallest sizes, a temporary folder only (a test, not a timing)"

_scratch: Path | None = None


def add_flag(parser: argparse.ArgumentParser) -> None:
    """``--smoke`` on a script's own parser."""
    parser.add_argument(FLAG, action="store_true", help=HELP)


def requested(argv: Sequence[str] | None = None) -> bool:
    """Whether ``--smoke`` is among ``argv`` (this process's arguments by default)."""
    return FLAG in (sys.argv[1:] if argv is None else argv)


def require(ok: bool, what: str) -> None:
    """End the benchmark with exit status 1 unless ``ok`` (``what``: the check, e.g. that
    both ways gave the same table); ``assert`` would vanish under ``python -O``."""
    if not ok:
        raise SystemExit(f"check failed: {what}")


def scratch() -> Path:
    """This process's temporary folder, made on first use and removed at exit."""
    global _scratch
    if _scratch is None:
        _scratch = Path(tempfile.mkdtemp(prefix="qsls-bench-smoke-"))
        atexit.register(shutil.rmtree, _scratch, ignore_errors=True)
    return _scratch


def work_dir(default: Path) -> Path:
    """Where a script keeps what it builds (bags, run folders): ``default`` (under
    ``benchmarks/_work``, reused across runs), or in smoke mode :func:`scratch`."""
    return scratch() / default.name if requested() else default
