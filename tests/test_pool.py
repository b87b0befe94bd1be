"""The process pool shared by the sweep and ``qsls fly`` (``core/pools.py``)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from qsls.pipeline.core.pools import run_tasks


def _pid_of_square(x: int) -> tuple[int, int]:
    time.sleep(0.05)  # long enough that both workers take tasks
    return x * x, os.getpid()


def _fail_first(arg: tuple[int, str]) -> int:
    i, folder = arg
    if i == 0:
        raise ValueError("task 0 fails")
    time.sleep(0.4)
    (Path(folder) / f"{i}.done").write_text("")
    return i


def test_results_come_back_in_task_order_from_worker_processes():
    done: list[int] = []
    out = run_tasks([(_pid_of_square, x) for x in range(8)], 2, done.append)
    assert [r for r, _ in out] == [x * x for x in range(8)]
    pids = {pid for _, pid in out}
    assert len(pids) == 2 and os.getpid() not in pids
    assert sorted(done) == list(range(8))


def test_one_job_or_one_task_runs_in_this_process():
    for tasks, jobs in (
        ([(_pid_of_square, 3), (_pid_of_square, 4)], 1),
        ([(_pid_of_square, 5)], 4),
    ):
        out = run_tasks(tasks, jobs)
        assert {pid for _, pid in out} == {os.getpid()}
    assert run_tasks([], 4) == []


def test_a_failing_task_cancels_the_tasks_not_started(tmp_path):
    tasks = [(_fail_first, (i, str(tmp_path))) for i in range(12)]
    with pytest.raises(ValueError, match="task 0 fails"):
        run_tasks(tasks, 2)
    finished = len(list(tmp_path.glob("*.done")))
    # the workers are terminated at once (run_pool): at most the tasks already running or in
    # the executor's call queue may have finished; without the cancel all eleven would run
    assert finished <= 6


SPY = """
import sys
from qsls.pipeline.control import sweep
from qsls.pipeline.control.options import SweepOptions

seen = []


def spy(tasks, jobs, done=None):  # what the pool would be given; no solve
    seen.append([jobs, all(m in sys.modules for m in sweep.WORKER_MODULES)])
    return [[{"index": p["index"], **p["grid"]} for p in chunk] for _, chunk in tasks]


sweep.run_tasks = spy
assert "cvxpy" not in sys.modules
opts = SweepOptions(T=4, S=0.05, eps_e=0.05, radius=1.0, delta=0.05, eps_w=0.01,
                    grid={"S": [0.01, 0.05]}, s_max_curve=False)
sweep.compute(opts, jobs=2)
print(seen)
"""


@pytest.mark.skipif(
    len(os.sched_getaffinity(0)) < 2 if hasattr(os, "sched_getaffinity") else True,
    reason="a pool of two needs two cores",
)
def test_the_sweep_imports_what_its_workers_need_before_forking_them():
    """``qsls sweep --jobs 2``: the workers are forked after the parent imported the solver
    and the synthesis (issue 37), so no worker imports them again in each pool phase."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", SPY], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "[[2, True]]"
