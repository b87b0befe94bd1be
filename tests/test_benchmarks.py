"""Every script in benchmarks/ runs at HEAD: each in smoke mode (``--smoke``,
benchmarks/smokemode.py) as a fresh process with this interpreter, from a temporary working
folder; it exits 0 and prints its figures, which parse and agree with themselves (the two
ways' checks passed, counts as sized, ratios finite and positive). A script added without a
smoke mode, or without its figures here, fails.

The runs start together when the module's first test needs them, two at a time (the two
cores the suite is sized for), in the order the selected tests run; each test waits for its
own. A smoke run's times say nothing about speed, so no test reads one as a speed."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BENCHMARKS = REPO / "benchmarks"
SHARED_REAL = REPO.parent / "shared" / "data" / "real"
HELPERS = {"smokemode.py"}
"""Modules in benchmarks/ that are not scripts."""
SCRIPTS = sorted(p.name for p in BENCHMARKS.glob("*.py") if p.name not in HELPERS)
REAL = {"bench_camera_euroc.py", "bench_rpe.py"}
"""Scripts that read ../shared/data/real (skipped when it is absent)."""
SLOW = {
    "bench_evaluate.py",
    "bench_ingest.py",
    "bench_ingest_process.py",
    "bench_run.py",
    "bench_sweep.py",
}
"""The longest smoke runs (fresh processes, a Dask cluster, a whole fly evaluation)."""
TIMEOUT_S = 300
NUM = r"(-?\d[\d,]*\.?\d*(?:e[-+]?\d+)?|nan|inf)"


def numbers(pattern: str, out: str, count: int | None = None) -> list[tuple[float, ...]]:
    """Every match of ``pattern`` (``{n}`` stands for a number) in ``out``, its groups as
    floats; at least one match, exactly ``count`` when given."""
    rx = re.compile(pattern.replace("{n}", NUM))
    found = [tuple(float(g.replace(",", "")) for g in m.groups()) for m in rx.finditer(out)]
    assert found, f"no line matches {pattern!r} in:\n{out}"
    assert count is None or len(found) == count, f"{len(found)} matches of {pattern!r}"
    return found


def positive(*xs: float) -> bool:
    return all(math.isfinite(x) and x > 0 for x in xs)


def camera(out: str) -> None:
    ((ratio,),) = numbers(r"{n}x faster than before; the same trajectory to the bit: True", out)
    ((cpu, speed, fps),) = numbers(r"camera regular \(whole flight\)\s+{n}\s+{n}\s+{n}", out)
    assert positive(ratio, cpu, speed, fps)


def camera_consistency(out: str) -> None:
    for mean, band in numbers(r"(?:regular|degraded)\s+all\s+{n}\s+{n}", out, 2):
        assert positive(mean) and 0 <= band <= 1
    for windows, accepted, *errors, within in numbers(
        r"(?:regular|degraded)\s+{n}\s+{n}" + r"\s+{n}" * 7, out, 2
    ):
        assert 0 < accepted <= windows and 0 <= within <= 1 and positive(*errors)
    numbers(r"all\s+\d+ \(flights with a reset: [01]\)", out)


def camera_euroc(out: str) -> None:
    for row in numbers(r"real VIO \(\S+\)\s+{n}\s+{n}", out, 2):
        assert positive(*row)
    for ate, rpe in numbers(r"camera loop, mean of 1\s+{n}\s+{n}", out, 2):
        assert positive(ate, rpe) and ate < 1.0


def evaluate(out: str) -> None:
    ((_, ratio),) = numbers(r"nearest 2000 x 300: KD-tree\s+{n}\s+{n}x faster", out)
    ((flights, _, speed),) = numbers(r"fly evaluation, {n} flights, jobs=2\s+{n}\s+{n}x", out)
    assert positive(ratio, speed) and flights == 5
    numbers(r"jobs=1 .* the same flights table: True", out)


def export(out: str) -> None:
    for (ticks,) in numbers(r"C -O2, (?:double|float) \(exported\)\s+{n}", out, 2):
        assert positive(ticks)
    ((stdlib,),) = numbers(r"stdlib Python module \(exported\)\s+{n}", out)
    ((naive,),) = numbers(r"naive: pure-Python nested loops\s+{n}", out)
    assert positive(stdlib, naive)
    ((du, u, dx, diff),) = numbers(r"\n\s+8\s+{n}\s+{n}\s+{n}\s+{n}\n", out + "\n")
    assert 0 < du < 1e-3 and positive(u) and 0 <= dx < 1e-3 and 0 <= diff < 1e-9
    for state, const, flops in numbers(
        r"8\s+(?:double|float)\s+{n}\s+\S+%\s+{n}\s+\S+%\s+{n}", out, 2
    ):
        assert positive(state, const, flops)


def fit(out: str) -> None:
    numbers(r"engine vs brute force: pairs equal True, max equal True", out)
    rows = numbers(r"(?:engine|brute|engine_x2|fit)\s+{n}\s+{n}\s+{n}", out, 5)
    assert all(0 < pairs <= candidates for _, pairs, candidates in rows)


def flights(out: str) -> None:
    for fast, slow, ratio in numbers(
        r"{n} s = \S+x real time per core; stepwise {n} s = \S+x; {n}x faster; identical logs: True",
        out, 2,
    ):  # fmt: skip
        assert positive(fast, slow, ratio)
    ((ratio,),) = numbers(r"-> {n}x more flights per CPU-second", out)
    assert ratio > 1  # the calibration flight writes no bag and ingests nothing
    numbers(
        r"2 calibration flights of the certified controller on a local pool of\s+2: {n} s wall", out
    )


def ingest(out: str) -> None:
    numbers(r"2000 Odometry\+PoseStamped messages per bag", out)
    rows = numbers(r"\n\S+ \([ab]\)[^|\n]*\|\s+{n} \(\s*{n}\)\s+{n} \(\s*{n}\)", out, 9)
    assert all(positive(*r) for r in rows)
    for (ratio,) in numbers(r"speed-up over the deserializer path\s+{n}x", out, 4):
        assert positive(ratio)
    assert len(numbers(r"\n(?:ros1|ros2-sqlite|ros2-mcap|mcap-zstd)\s+\|\s+{n}\s+{n}", out)) == 4


def ingest_process(out: str) -> None:
    rows = numbers(
        r"\n(?:ros1|ros2-sqlite3|ros2-mcap|mcap \(zstd\))\s+\|\s+{n} \({n}\) \|\s+{n} \({n}\)",
        out,
        4,
    )
    assert all(positive(*r) for r in rows)
    for n, qsls_mb, reader_mb in numbers(
        r"ros1\s+{n} \|\s+\S+ \(\s*\S+\)\s+{n} \|\s+\S+ \(\s*\S+\)\s+{n}", out, 2
    ):
        assert n in (2000, 4000) and positive(qsls_mb, reader_mb)


def rpe(out: str) -> None:
    rows = numbers(r"\|\s+{n}\s+\|\s+{n}\s+\|\s+{n}\s+\|\s+{n}[^|]*\|\s+{n}", out, 12)
    assert all(
        positive(w, speed, err, ratio) and -1 <= rho <= 1 for w, speed, err, ratio, rho in rows
    )


def run(out: str) -> None:
    rows = numbers(r"\|\s+{n} \({n}\) \|\s+{n} \({n}\)\s+{n}x", out, 2)
    assert all(positive(*r) for r in rows)
    numbers(r"floor, qsls --version: {n} s \({n} s CPU\)", out)


def simulate(out: str) -> None:
    ((wall, cpu),) = numbers(r"like for like \(loop only, 100 Hz\): {n}x wall, {n}x cpu", out)
    assert positive(wall, cpu)
    ((diff,),) = numbers(r"max \|p_qsls - p_rotorpy\| over the same flight: {n} mm", out)
    assert math.isfinite(diff) and diff >= 0
    ((msgs, mb),) = numbers(r"200 Hz, VIO\+mocap, ros1 written\s+\S+\s+\S+\s+{n} msgs, {n} MB", out)
    assert positive(msgs, mb)


def sweep(out: str) -> None:
    ((points, feasible),) = numbers(r"{n}-point sweep \(the smoke grid\): {n} feasible", out)
    assert points == 6 and 0 < feasible < points
    ((necessary, _),) = numbers(
        r"{n} by the necessary condition S \+ eps_e/r < 1, {n} by S above", out
    )
    assert necessary == 1
    for wall, cpu in numbers(
        r"(?:1 process|2 processes|Dask, 2 workers)\s+{n}\s+{n}\s+True", out, 3
    ):
        assert positive(wall, cpu)
    numbers(r"(?:per setting|per T and radius)\s+\d+\s+\d+\s+\S+\s+True", out, 2)


def synth(out: str) -> None:
    objectives = [
        r[-1] for r in numbers(r"\n(?:eliminated|vectorized|naive)[^\n]*\s{n}(?=\n)", out, 5)
    ]
    assert all(abs(o / objectives[0] - 1) < 1e-5 for o in objectives)
    for (rel,) in numbers(r"objective relative difference {n};", out, 2):
        assert 0 <= rel < 1e-5
    ((points, feasible),) = numbers(r"{n}-point sweep \([^)]*\), {n} feasible", out)
    assert points == 4 and 0 < feasible <= points
    ((speedup,),) = numbers(r"premise: [^\n]*\n[^\n]*\n[^\n]*\n[^\n]*\nspeed-up: {n}x", out)
    assert positive(speedup)


def fresh(out: str) -> None:
    for row in numbers(
        r"(?:cached \(fresh_env\)|compiled on every start)\s+{n}\s+{n}\s+{n}", out, 2
    ):
        assert positive(*row)
    ((wall, cpu),) = numbers(r"the cache saves {n}x wall, {n}x CPU", out)
    assert positive(wall, cpu)


def tune_pd(out: str) -> None:
    grid = numbers(r"kp\s+{n}\s+kd\s+{n}\s+circle tracking RMS {n} m", out, 2)
    ((score,),) = numbers(r"tuned \(camera, 10 Hz\): kp \([^)]*\) kd \([^)]*\) score {n} m", out)
    assert positive(score) and score == min(r[2] for r in grid)


def ulog(out: str) -> None:
    ((minutes, msgs, mb, vio),) = numbers(
        r"PX4 ULog: {n} min, {n} messages in 5 topics, {n} MB \(written in \S+ s; VIO and mocap "
        r"odometry at 200 Hz, {n} VIO messages\)", out)  # fmt: skip
    assert minutes == 0.2 and msgs == 15000 and vio == 2400 and positive(mb)
    for _wall, _cpu, rss in numbers(
        r"(?m)^(?:read_odometry\(|pyulog |qsls ingest )[^\n]*?\s{n}\s+{n}\s+{n}$", out, 4
    ):
        assert positive(rss)
    ((speed, _extra, _naive, size),) = numbers(
        r"read_odometry: {n}x the naive way's speed; peak RSS above the imports {n} MB "
        r"\(naive {n} MB\) for a {n} MB log", out)  # fmt: skip
    assert positive(speed, size)


def monitor_reach(out: str) -> None:
    """Each family's flight is explained, explained apart, undecided or broken at a time, once;
    no window trip precedes the earliest possible sound trip."""
    rows = [
        [c.strip() for c in line.strip("|").split("|")]
        for line in out.splitlines()
        if line.startswith(("| nominal |", "| wind 3.0 m/s |"))
    ]
    assert len(rows) == 2, out
    for _, n, broken, explained, apart, undecided, exact, tripped, at, before in rows:
        n, broken, explained, apart, undecided = map(int, (n, broken, explained, apart, undecided))
        assert n == 1 and 0 <= broken <= n
        assert explained + apart + undecided + (exact != "-") == n  # each flight in one column
        assert exact == "-" or positive(float(exact))
        assert (at == "-") == (tripped == "0") and before == "0"


FIGURES: dict[str, Callable[[str], None]] = {
    "bench_camera.py": camera,
    "bench_camera_consistency.py": camera_consistency,
    "bench_camera_euroc.py": camera_euroc,
    "bench_evaluate.py": evaluate,
    "bench_export.py": export,
    "bench_fit.py": fit,
    "bench_flights.py": flights,
    "bench_ingest.py": ingest,
    "bench_ingest_process.py": ingest_process,
    "bench_rpe.py": rpe,
    "bench_run.py": run,
    "bench_simulate.py": simulate,
    "bench_ulog.py": ulog,
    "bench_sweep.py": sweep,
    "bench_synth.py": synth,
    "fresh.py": fresh,
    "monitor_reach.py": monitor_reach,
    "tune_pd.py": tune_pd,
}
"""What each script's smoke run must print."""


def _smoke(script: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}  # no __pycache__ in benchmarks/
    return subprocess.run(
        [sys.executable, str(BENCHMARKS / script), "--smoke"],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=TIMEOUT_S,
    )  # fmt: skip


def _skip_reason(script: str) -> str | None:
    if script in REAL and not SHARED_REAL.is_dir():
        return "../shared/data/real is not present (only the project's own data is)"
    return None


def _repo_files() -> set[str]:
    """Untracked and ignored paths of the checkout (``git status``), bytecode caches aside."""
    out = subprocess.run(
        ["git", "status", "--porcelain", "--ignored", "--untracked-files=normal"],
        cwd=REPO, capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    return {line for line in out.splitlines() if "__pycache__" not in line}


@pytest.fixture(scope="module")
def smoke_runs(request, tmp_path_factory):
    """``{script: Future of its CompletedProcess}`` for the scripts the session's selected
    tests need, started two at a time in the tests' order; and the checkout's untracked and
    ignored files before them."""
    here = request.node.nodeid
    wanted = [
        item.callspec.params["script"]
        for item in request.session.items
        if item.nodeid.startswith(here) and hasattr(item, "callspec")
    ]
    before = _repo_files()
    pool = ThreadPoolExecutor(2)
    runs: dict[str, Future[subprocess.CompletedProcess[str]]] = {}
    for script in dict.fromkeys(wanted):
        if _skip_reason(script) is None:
            runs[script] = pool.submit(_smoke, script, tmp_path_factory.mktemp(script[:-3]))
    yield runs, before
    pool.shutdown(wait=True, cancel_futures=True)


def test_every_script_has_its_figures():
    assert SCRIPTS and sorted(FIGURES) == SCRIPTS


@pytest.mark.parametrize(
    "script",
    [
        pytest.param(
            s,
            marks=[
                m for m, on in ((pytest.mark.slow, s in SLOW), (pytest.mark.real, s in REAL)) if on
            ],
            id=s[:-3],
        )
        for s in SCRIPTS
    ],
)
def test_benchmark_smoke(script, smoke_runs):
    reason = _skip_reason(script)
    if reason:
        pytest.skip(reason)
    runs, _ = smoke_runs
    proc = runs[script].result()
    assert proc.returncode == 0, (
        f"{script} --smoke failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    )
    assert script in FIGURES, f"{script}: no figures check in tests/test_benchmarks.py"
    FIGURES[script](proc.stdout)


def test_smoke_runs_write_nothing_into_the_checkout(smoke_runs):
    runs, before = smoke_runs
    for future in runs.values():
        future.result()
    assert _repo_files() == before
