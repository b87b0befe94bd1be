"""A fast start: the CLI imports little, ``qsls ingest`` never loads the solver or plotting stacks
nor scipy (its offset search is a golden-section search, its differentiator a numpy
Savitzky-Golay that equals scipy's)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from qsls.pipeline.ingest.align import savgol_derivative
from tests.bagfixtures import bag_name, make_flight, write_flight

HEAVY = ("cvxpy", "scipy", "matplotlib")


@pytest.mark.parametrize("m", [5, 7, 21, 41])
def test_savgol_derivative_equals_scipy(m):
    from scipy.signal import savgol_filter

    rng = np.random.default_rng(m)
    x = np.cumsum(rng.normal(size=(300, 3)), axis=0)
    want = savgol_filter(x, m, 2, deriv=1, delta=0.01, axis=0, mode="interp")
    got = savgol_derivative(x, m, 0.01)
    assert np.abs(got - want).max() <= 1e-12 * np.abs(want).max()
    # and it differentiates a parabola exactly, edges included
    t = np.arange(50) * 0.02
    p = (3 * t**2 - t + 2)[:, None]
    np.testing.assert_allclose(
        savgol_derivative(p, m if m < 50 else 5, 0.02)[:, 0], 6 * t - 1, atol=1e-9
    )


def _run(code: str, tmp_path: Path) -> str:
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=120
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


def test_cli_import_loads_no_heavy_module(tmp_path):
    loaded = _run(
        f"import sys, qsls.cli.main\nprint(sorted(m for m in {HEAVY!r} if m in sys.modules))\n",
        tmp_path,
    )
    assert loaded.strip() == "[]"


@pytest.mark.parametrize("fmt", ["tum", "ros1", "ros2-sqlite", "ros2-mcap"])
def test_ingest_loads_neither_solver_nor_plotting(tmp_path, fmt):
    """A real ingest in a fresh interpreter, TUM files (velocity from the differentiator) or
    a bag read through the fast paths, loads none of them, nor pandas (flight.parquet is
    written from a pyarrow table), nor rich off a terminal (the summary is drawn by
    ``box_table``), nor ``numpy.ma`` (which ``np.median`` and ``np.unique`` import)."""
    f = make_flight(duration=10.0, dropouts=(), noise_m=0.0005)
    if fmt == "tum":
        for name, s in (("est.txt", f.vio), ("gt.txt", f.truth)):
            (tmp_path / name).write_text(
                "".join(
                    f"{n // 10**9}.{n % 10**9:09d} {' '.join(f'{x:.12g}' for x in [*a, *b])}\n"
                    for n, a, b in zip(s.header_ns, s.position, s.orientation, strict=True)
                )
            )
        args = "'--vio', 'est.txt', '--truth', 'gt.txt'"
    else:
        bag = write_flight(tmp_path / bag_name(fmt), fmt, f)
        args = f"{bag.name!r}"
    loaded = _run(
        "import sys\n"
        "from qsls.cli.main import app\n"
        "try:\n"
        f"    app(['ingest', {args}, '--out', 'o'])\n"
        "except SystemExit as e:\n"
        "    assert not e.code, e.code\n"
        f"print(sorted(m for m in {(*HEAVY, 'pandas', 'rich', 'numpy.ma')!r} if m in sys.modules))\n",
        tmp_path,
    )
    assert (tmp_path / "o" / "flight.parquet").is_file()
    assert loaded.strip().splitlines()[-1] == "[]"


def _qsls(args: list[str], tmp_path: Path, full: bool) -> tuple[str, int]:
    """``python -m qsls.cli.main ARGS`` (only the named command registered), or with
    ``full`` the app an import builds (every command) called with ARGS; same terminal."""
    import os

    code = (
        "import sys\nfrom qsls.cli.main import app\n"
        f"app({args!r}, prog_name='python -m qsls.cli.main')\n"
    )
    cmd = ["-c", code] if full else ["-m", "qsls.cli.main", *args]
    out = subprocess.run(
        [sys.executable, *cmd], capture_output=True, text=True, cwd=tmp_path, timeout=120,
        env={**os.environ, "COLUMNS": "100", "TERM": "dumb"},
    )  # fmt: skip
    return out.stdout + out.stderr, out.returncode


def test_command_line_builds_only_the_named_command(tmp_path):
    """``qsls ingest ...`` registers ingest alone (the other command modules are never
    imported), yet its help and its errors are those of the app with every command (what an
    import of ``qsls.cli.main`` builds); an unknown command still gets the near names."""
    from qsls.cli.main import COMMANDS

    code = (
        "import runpy, sys\n"
        "sys.argv = ['qsls', 'ingest', '--help']\n"
        "try:\n"
        "    runpy.run_module('qsls.cli.main', run_name='__main__')\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print(sorted(m for _, m in {COMMANDS!r} if 'qsls.cli.' + m in sys.modules))\n"
    )
    assert _run(code, tmp_path).strip().splitlines()[-1] == "['ingest']"
    for args in (["ingest", "--help"], ["fit", "--help"], ["ingest", "--bogus"], ["ingst"]):
        got = _qsls(args, tmp_path, full=False)
        assert got == _qsls(args, tmp_path, full=True), args
        assert ("Usage:" in got[0]) and (got[1] == (0 if "--help" in args else 2)), args
    assert "Did you mean 'ingest'?" in _qsls(["ingst"], tmp_path, full=False)[0]


def test_pydantic_plugins_off_unless_the_user_says(tmp_path):
    """The command sets ``PYDANTIC_DISABLE_PLUGINS=__all__`` (no plugin lookup at start-up)
    only when the user has not set it."""
    import os

    code = (
        "import os, sys\nsys.argv = ['qsls']\nimport qsls.cli.main\n"
        "print(os.environ['PYDANTIC_DISABLE_PLUGINS'])\n"
    )
    assert _run(code, tmp_path).strip() == "__all__"
    env = {**os.environ, "PYDANTIC_DISABLE_PLUGINS": "logfire"}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env
    )
    assert out.stdout.strip() == "logfire"


def test_differentiate_resamples_only_stamps_off_their_grid(monkeypatch):
    """Stamps on their median-spacing grid give the Savitzky-Golay slope of the samples as
    they are, without resampling; one stamp 1 us off the grid sends the stream through the
    resampling (to the grid and back), which moves the velocity by micrometres per second."""
    from qsls.pipeline.ingest import align

    calls = []
    resample = align.interp_rows
    monkeypatch.setattr(align, "interp_rows", lambda *a: calls.append(1) or resample(*a))
    t = np.arange(20_000, dtype=np.int64) * 5_000_000 + 1_700_000_000_000_000_000
    p = np.column_stack([np.sin(np.arange(20_000) * 0.001 * k) for k in (1, 2, 3)])
    v = align.differentiate(t, p, 0.1, 50_000_000)
    assert calls == []
    np.testing.assert_allclose(v, savgol_derivative(p, 21, 0.005), rtol=1e-9, atol=0)
    jitter = t.copy()
    jitter[5000] += 1000
    w = align.differentiate(jitter, p, 0.1, 50_000_000)
    assert len(calls) == 2 and 0 < np.abs(w - v).max() < 1e-5
