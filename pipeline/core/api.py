"""Lazy public APIs for the stage packages (PEP 562).

Each stage package lists its public names in its ``__init__`` and imports a module only when
one of its names is first used, so that ``import qsls.pipeline.ingest`` does not pull in the
solver stack and the packages never import each other in a cycle.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_api(package: str, names: Mapping[str, str]) -> tuple[list[str], Callable[[str], Any]]:
    """``(__all__, __getattr__)`` for ``package`` whose public ``names`` map to their module."""

    def __getattr__(name: str) -> Any:
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{module}"), name)

    return sorted(names), __getattr__
