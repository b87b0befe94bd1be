"""Shared fixtures: the real-data folder (skipped when absent), temporary run folders."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_REAL = REPO.parent / "shared" / "data" / "real"


@pytest.fixture(scope="session")
def real_data() -> Path:
    """``../shared/data/real``; tests that use it skip cleanly when it is absent."""
    if not SHARED_REAL.is_dir():
        pytest.skip("../shared/data/real is not present (only the project's own data is)")
    return SHARED_REAL
