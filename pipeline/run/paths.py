"""Paths in a run config: relative to the config file's folder (the one helper for it)."""

from __future__ import annotations

from pathlib import Path


def resolve_path(base: Path, p: str | Path) -> Path:
    """``p`` with ``~`` expanded, taken relative to ``base`` when relative, made absolute."""
    q = Path(p).expanduser()
    return (q if q.is_absolute() else Path(base) / q).resolve()
