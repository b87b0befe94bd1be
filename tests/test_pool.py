"""The process pool shared by the sweep and ``evaluate --fly`` (``core/pools.py``)."""

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
