"""Timing commands as fresh processes, what a user types (interpreter start and imports in).

An installed qsls has compiled bytecode (pip compiles it at install time); a source tree
run with ``PYTHONDONTWRITEBYTECODE`` (as in CI) compiles every qsls module on every start,
which is not what a user pays. :func:`fresh_env` gives the children a bytecode cache
under ``benchmarks/_work/pycache``, and :func:`best_walls` runs each command once untimed to
fill it. CPU seconds (user + system of the child) are reported beside wall seconds: they
move less than wall time on a machine shared with other work.
"""

from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

WORK = Path(__file__).resolve().parent / "_work"


def fresh_env() -> dict[str, str]:
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
    work slows both sides of a ratio alike), after one untimed run of each; a failing
    command ends the benchmark."""
    env = fresh_env()
    for cmd in cmds.values():
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


def peak_run(cmd: list[str], cwd: Path | None = None) -> tuple[float, float, float, str]:
    """One fresh run of ``cmd``: ``(wall s, CPU s, peak RSS MB, stdout)``, the peak resident
    set of that process alone (``os.wait4``'s ``ru_maxrss``).

    Through a small launcher process: Linux folds the memory map's high-water mark a
    process had when it forked into its child's ``ru_maxrss`` at ``exec``, so a child of
    this (large) benchmark process would report at least this process's own size; the
    launcher is small when it forks the command."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        out, err = Path(tmp) / "out", Path(tmp) / "err"
        done = subprocess.run(
            [sys.executable, "-c", _LAUNCHER, str(out), str(err), *cmd],
            capture_output=True, text=True, cwd=cwd, env=fresh_env(),
        )  # fmt: skip
        if done.returncode:
            raise SystemExit(f"launcher failed: {done.stderr.strip()[-400:]}")
        wall, cpu, maxrss_kb, code = done.stdout.split()
        if int(code):
            raise SystemExit(f"{' '.join(cmd[:4])} ... failed: {err.read_text().strip()[-400:]}")
        return float(wall), float(cpu), int(maxrss_kb) / 1024, out.read_text()
