"""One process pool for the stages that run many independent tasks (the sweep's grid chunks,
the flights of ``evaluate --fly``).

Workers are forked where the platform can (they inherit the imported solver and simulator;
spawning would re-import them per worker). When a task raises, or the run is interrupted
(Ctrl-C, or SIGTERM, which the CLI turns into a ``KeyboardInterrupt`` and whose handler ends
the workers), the tasks not started are cancelled and the pool is shut down before the
exception goes on, so no worker keeps running the rest of the batch.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeVar

R = TypeVar("R")

Task = tuple[Callable[[Any], R], Any]
"""``(fn, arg)``: the pool calls ``fn(arg)`` (both picklable: a module-level function)."""


def run_tasks(
    tasks: Sequence[Task[R]], jobs: int, done: Callable[[int], None] | None = None
) -> list[R]:
    """``[fn(arg) for fn, arg in tasks]``, in the order of ``tasks``; on ``jobs`` worker
    processes, or in this process when ``jobs <= 1`` or there is a single task.

    ``done(i)`` is called in this process when task ``i`` has finished (for progress)."""
    results: list[Any] = [None] * len(tasks)
    if jobs <= 1 or len(tasks) <= 1:
        for i, (fn, arg) in enumerate(tasks):
            results[i] = fn(arg)
            if done is not None:
                done(i)
        return results
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
    with ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=ctx) as pool:
        futures = {pool.submit(fn, arg): i for i, (fn, arg) in enumerate(tasks)}
        try:
            for fut in as_completed(futures):
                i = futures[fut]
                results[i] = fut.result()
                if done is not None:
                    done(i)
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    return results
