"""Paths in a run config: relative to the config file's folder (the one helper for it), with
environment variables (docs/run.md#paths)."""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path

from qsls.pipeline.core.errors import ConfigError

VARIABLE = re.compile(r"\$\{(\w+)(?::-([^}]*))?\}|\$(\w+)")
"""``${NAME}``, ``${NAME:-default}`` or ``$NAME`` in a config path."""


def expand(p: str) -> str:
    """``p`` with each variable replaced: a set variable by its value made absolute (relative
    values are taken from the working folder, as a shell would), an unset or empty one by its
    default (``${NAME:-default}``, kept relative: the config's folder), else refused."""

    def value(m: re.Match[str]) -> str:
        name = m.group(1) or m.group(3)
        got = os.environ.get(name, "")
        if got:
            return str(Path(got).expanduser().resolve())
        if m.group(2) is not None:
            return m.group(2)
        raise ConfigError(f"path {p!r}: the environment variable {name} is not set")

    return VARIABLE.sub(value, p)


def resolve_path(base: Path, p: str | Path) -> Path:
    """``p`` with variables (:func:`expand`) and ``~`` expanded, taken relative to ``base`` when
    relative, made absolute."""
    q = Path(expand(str(p))).expanduser()
    return (q if q.is_absolute() else Path(base) / q).resolve()


def missing_hint(raw: Iterable[str | Path]) -> str:
    """What to do about a missing file read through a variable (``''`` for plain paths): say
    where the variable points and how to set it."""
    hints = []
    for m in (m for p in raw for m in VARIABLE.finditer(str(p))):
        name, default = m.group(1) or m.group(3), m.group(2)
        got = os.environ.get(name, "")
        where = f"{name} is {got}" if got else f"{name} is not set"
        if not got and default is not None:
            where += f", so the config's {default} is used"
        hint = f"{where}: set {name} to the folder these paths start from"
        if hint not in hints:
            hints.append(hint)
    return "".join(f" ({h})" for h in hints)
