"""Shared fixtures: the real-data folder (skipped when absent), temporary run folders."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_REAL = REPO.parent / "shared" / "data" / "real"


def pytest_xdist_auto_num_workers(config) -> int:
    """``-n auto``: one worker per core, at most 4 (many tests fly on a pool of all cores
    themselves, so more workers only oversubscribe)."""
    import os

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(4, cores or 1))


@pytest.fixture(scope="session")
def quickstart_session(tmp_path_factory):
    """``qsls run configs/quickstart.yaml`` once per session, from a clean folder: (work
    folder, config, the process, seconds, its data files as they were when it ended, keyed
    ``runs/quickstart/...``). The work folder belongs to test_run.py's tests (they rerun and
    edit it); others use only the snapshot."""
    import subprocess
    import sys
    import time

    from tests.test_run import QUICKSTART, _data_files

    work = tmp_path_factory.mktemp("qs")
    cfg = work / "quickstart.yaml"
    cfg.write_text(QUICKSTART.read_text())
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", "run", str(cfg)],
        cwd=work, capture_output=True, text=True,
    )  # fmt: skip
    elapsed = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr[-3000:]
    return work, cfg, proc, elapsed, _data_files(work)


@pytest.fixture(scope="session")
def gcc() -> str:
    """The system's C compiler (the export tests compile what ``qsls export`` writes); the
    test skips where there is none."""
    from qsls.pipeline.export.cbuild import find_compiler

    cc = find_compiler("gcc")
    if cc is None:
        pytest.skip("no gcc on this machine")
    return str(cc)


@pytest.fixture(scope="session")
def real_data() -> Path:
    """``../shared/data/real``; tests that use it skip cleanly when it is absent."""
    if not SHARED_REAL.is_dir():
        pytest.skip("../shared/data/real is not present (only the project's own data is)")
    return SHARED_REAL


# --------------------------------------------------------------------------- gamma_strict <= gamma
def _strict_above_gamma(root: Path) -> list[str]:
    """Certificates under ``root`` whose paper's ``gamma_strict`` exceeds ``gamma`` (both finite).

    ``R0 = eps_e`` unless set, so ``gamma_strict = R0 / (1 - S ||Phi_xy||)`` never exceeds
    ``gamma = (eps_e + S a) / (1 - S ||Phi_xy||)`` (docs/guarantee.md#the-present-theorem)."""
    import math

    import yaml

    bad = []
    for f in sorted(root.rglob("certificate.yaml")):
        try:
            doc = yaml.safe_load(f.read_text())
        except (OSError, yaml.YAMLError):
            continue
        if not isinstance(doc, dict):
            continue
        g, s = doc.get("gamma"), doc.get("gamma_strict")
        nums = [v for v in (g, s) if isinstance(v, int | float) and math.isfinite(v)]
        if len(nums) == 2 and s > g:
            bad.append(f"{f}: gamma_strict = {s} > gamma = {g}")
    return bad


@pytest.fixture(autouse=True)
def _gamma_strict_at_most_gamma(request):
    """After each test: every certificate.yaml in its tmp_path has gamma_strict <= gamma."""
    # taken before the test (so torn down after this fixture), only where the test uses it
    root = request.getfixturevalue("tmp_path") if "tmp_path" in request.fixturenames else None
    yield
    if root is not None:
        bad = _strict_above_gamma(root)
        assert not bad, "; ".join(bad)


@pytest.fixture(autouse=True, scope="session")
def _gamma_strict_at_most_gamma_everywhere(tmp_path_factory):
    """At the end of the session: the same over every folder the suite wrote (module- and
    session-scoped fixtures included)."""
    yield
    bad = _strict_above_gamma(tmp_path_factory.getbasetemp())
    assert not bad, "; ".join(bad)


@pytest.fixture(autouse=True, scope="session")
def _nothing_written_into_the_checkout():
    """The suite writes under pytest's temporary folders only: no new entry in the checkout's
    reports/, runs/ or top level (issue 26: reports/test-artifacts/ was written there)."""

    def entries() -> set[str]:
        top = {p.name for p in REPO.iterdir()}
        sub = {f"{d}/{p.name}" for d in ("reports", "runs") if (REPO / d).is_dir()
               for p in (REPO / d).iterdir()}  # fmt: skip
        return top | sub

    before = entries()
    yield
    new = sorted(e for e in entries() - before if not e.startswith((".", "__")))
    assert not new, f"the test suite wrote into the checkout: {new}"
