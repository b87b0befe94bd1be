"""Timing commands as fresh processes, what a user types (interpreter start and imports in).

An installed qsls has compiled bytecode (pip compiles it at install time); a source tree
run with ``PYTHONDONTWRITEBYTECODE`` (as in CI) compiles every qsls module on every start,
which is not what a user pays. :func:`fresh_env` gives the children a bytecode cache
under ``benchmarks/_work/pycache``, and :func:`best_wall` runs each command once untimed to
fill it.
"""

from __future__ import annotations

import os
import resource
import subprocess
import time
from pathlib import Path

WORK = Path(__file__).resolve().parent / "_work"


def fresh_env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = str(WORK / "pycache")
    return env


def best_wall(cmd: list[str], repeat: int, cwd: Path | None = None) -> tuple[float, float, str]:
    """(best wall seconds, CPU seconds of that run, its stdout) of ``repeat`` fresh runs of
    ``cmd`` after one untimed run; a failing command ends the benchmark with its error."""
    env = fresh_env()
    best, cpu, out = float("inf"), 0.0, ""
    for k in range(repeat + 1):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        done = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd, env=env)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if done.returncode:
            raise SystemExit(f"{' '.join(cmd[:4])} ... failed: {done.stderr.strip()[-400:]}")
        used = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        if k and wall < best:
            best, cpu, out = wall, used, done.stdout
    return best, cpu, out
