"""Timing commands as fresh processes, what a user types (interpreter start and imports in).

An installed qsls has compiled bytecode (pip compiles it at install time); a source tree
run with ``PYTHONDONTWRITEBYTECODE`` (as in CI) compiles every qsls module on every start,
which is not what a user pays. :func:`fresh_env` gives the children a bytecode cache
under ``benchmarks/_work/pycache``, and :func:`best_walls` runs each command once untimed to
fill it. CPU seconds (user + system of the child) are reported beside wall seconds: they
move less than wall time on a machine shared with other work.

In smoke mode (``smokemode.py``) the children keep this process's environment (the usual
bytecode caches: a cache of their own would compile every module once, most of a smoke run)
and no command runs untimed first.

Run on its own, ``python benchmarks/fresh.py [--repeat N] [--smoke]`` measures what the cache
is for: ``qsls --version`` as a fresh process with the bytecode cache against compiling every
module on every start (``PYTHONDONTWRITEBYTECODE`` and an empty cache), best of ``N`` (5) each,
taken in turns, and the peak resident set of each.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from smokemode import add_flag, requested, require, work_dir

WORK = work_dir(Path(__file__).resolve().parent / "_work")
SMOKE = requested()


def fresh_env() -> dict[str, str]:
    if SMOKE:
        return dict(os.environ)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = str(WORK / "pycache")
    return env


def _once(cmd: list[str], cwd: Path | None, env: dict[str, str]) -> tuple[float, float, str]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode:
        raise SystemExit(f"{' '.join(cmd[:4])} ... failed: {done.stderr.strip()[-400:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, done.stdout


def _runs(
    cmds: dict[str, list[str]], repeat: int, cwd: Path | None
) -> dict[str, list[tuple[float, float, str]]]:
    """``repeat`` fresh runs of each command, taken in turns (a machine shared with other
    work slows both sides of a ratio alike), after one untimed run of each (not in smoke
    mode); a failing command ends the benchmark."""
    env = fresh_env()
    for cmd in [] if SMOKE else cmds.values():
        _once(cmd, cwd, env)
    runs: dict[str, list[tuple[float, float, str]]] = {k: [] for k in cmds}
    for _ in range(repeat):
        for label, cmd in cmds.items():
            runs[label].append(_once(cmd, cwd, env))
    return runs


def best_walls(
    cmds: dict[str, list[str]], repeat: int, cwd: Path | None = None
) -> dict[str, tuple[float, float, str]]:
    """``{label: (best wall seconds, least CPU seconds, stdout)}`` over ``repeat`` fresh runs
    of each command (:func:`_runs`); ``inf`` for ``repeat`` 0 (the untimed run only)."""
    return {
        k: (min((r[0] for r in v), default=float("inf")),
            min((r[1] for r in v), default=float("inf")), v[-1][2] if v else "")
        for k, v in _runs(cmds, repeat, cwd).items()
    }  # fmt: skip


def median_runs(
    cmds: dict[str, list[str]], repeat: int, cwd: Path | None = None
) -> dict[str, tuple[float, float, str]]:
    """``{label: (median wall seconds, median CPU seconds, stdout)}`` over ``repeat`` fresh
    runs of each command (:func:`_runs`)."""
    return {
        k: (statistics.median(r[0] for r in v), statistics.median(r[1] for r in v), v[-1][2])
        for k, v in _runs(cmds, repeat, cwd).items()
    }


_LAUNCHER = r"""
import os, subprocess, sys, time
t0 = time.perf_counter()
with open(sys.argv[1], "wb") as out, open(sys.argv[2], "wb") as err:
    proc = subprocess.Popen(sys.argv[3:], stdout=out, stderr=err)
    _, status, ru = os.wait4(proc.pid, 0)
print(time.perf_counter() - t0, ru.ru_utime + ru.ru_stime, ru.ru_maxrss,
      os.waitstatus_to_exitcode(status))
"""


def peak_run(
    cmd: list[str], cwd: Path | None = None, env: dict[str, str] | None = None
) -> tuple[float, float, float, str]:
    """One fresh run of ``cmd``: ``(wall s, CPU s, peak RSS MB, stdout)``, the peak resident
    set of that process alone (``os.wait4``'s ``ru_maxrss``); ``env`` default
    :func:`fresh_env`.

    Through a small launcher process: Linux folds the memory map's high-water mark a
    process had when it forked into its child's ``ru_maxrss`` at ``exec``, so a child of
    this (large) benchmark process would report at least this process's own size; the
    launcher is small when it forks the command."""
    with tempfile.TemporaryDirectory() as tmp:
        out, err = Path(tmp) / "out", Path(tmp) / "err"
        done = subprocess.run(
            [sys.executable, "-c", _LAUNCHER, str(out), str(err), *cmd],
            capture_output=True, text=True, cwd=cwd, env=env or fresh_env(),
        )  # fmt: skip
        if done.returncode:
            raise SystemExit(f"launcher failed: {done.stderr.strip()[-400:]}")
        wall, cpu, maxrss_kb, code = done.stdout.split()
        if int(code):
            raise SystemExit(f"{' '.join(cmd[:4])} ... failed: {err.read_text().strip()[-400:]}")
        return float(wall), float(cpu), int(maxrss_kb) / 1024, out.read_text()


def main() -> None:
    ap = argparse.ArgumentParser(description="qsls --version with and without a bytecode cache")
    ap.add_argument("--repeat", type=int, default=5, help="fresh processes per cell (best)")
    add_flag(ap)
    args = ap.parse_args()
    repeat = 1 if args.smoke else args.repeat
    cmd = [sys.executable, "-m", "qsls.cli.main", "--version"]
    with tempfile.TemporaryDirectory(prefix="qsls-empty-pycache-") as empty:
        compile_env = {**fresh_env(), "PYTHONDONTWRITEBYTECODE": "1", "PYTHONPYCACHEPREFIX": empty}
        env = fresh_env()
        if not SMOKE:
            _once(cmd, None, env)  # fills the cache
        cached, compiled = [], []
        for _ in range(repeat):
            cached.append(_once(cmd, None, env))
            compiled.append(_once(cmd, None, compile_env))
        peak = peak_run(cmd), peak_run(cmd, env=compile_env)
    require(
        cached[-1][2] == compiled[-1][2] and "qsls" in cached[-1][2],
        "both ways print the same version",
    )
    print(f"qsls --version as a fresh process, best of {repeat} taken in turns:\n")
    head = f"{'bytecode':34s} {'wall s':>7s} {'CPU s':>6s} {'peak MB':>8s}"
    print(head)
    print("-" * len(head))
    rows = (("cached (fresh_env)", cached, peak[0]), ("compiled on every start", compiled, peak[1]))
    for label, runs, pk in rows:
        wall, cpu = min(r[0] for r in runs), min(r[1] for r in runs)
        print(f"{label:34s} {wall:7.2f} {cpu:6.2f} {pk[2]:8.0f}")
    c_wall, k_wall = min(r[0] for r in cached), min(r[0] for r in compiled)
    c_cpu, k_cpu = min(r[1] for r in cached), min(r[1] for r in compiled)
    print(f"\nthe cache saves {k_wall / c_wall:.2f}x wall, {k_cpu / c_cpu:.2f}x CPU")


if __name__ == "__main__":
    main()
