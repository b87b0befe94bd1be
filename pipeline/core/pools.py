"""Local process pools that stop at once when interrupted.

``with ProcessPoolExecutor(...)`` waits, on the way out, for the tasks its workers are
running: a Ctrl-C during ``qsls sweep --jobs 2`` took 11-20 s to exit while each worker
finished its solve. :func:`run_pool` instead cancels the queued tasks and terminates the
workers on any exception (KeyboardInterrupt included), as SIGTERM does; workers ignore
SIGINT (Ctrl-C reaches the whole process group; the parent alone answers it).
"""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from qsls.pipeline.core.cluster import run_dask


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_pool(
    fn: Callable[[Any], Any], args: Sequence[Any], workers: int
) -> Iterator[tuple[int, Any]]:
    """``(index, fn(args[index]))`` as they complete, on ``workers`` forked processes."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # fork: workers inherit the imported modules (spawn would re-import them per worker)
    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_ignore_sigint)
    try:
        futs = {pool.submit(fn, a): i for i, a in enumerate(args)}
        for fut in as_completed(futs):
            yield futs[fut], fut.result()
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown()


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity; ``os.cpu_count()`` elsewhere)."""
    import os

    try:
        return len(os.sched_getaffinity(0)) or 1
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def pool_size(jobs: int | None) -> int:
    """Worker processes for ``jobs``: 0 or None means every available core, and never more
    processes than cores (``--jobs 64`` on 2 cores would only make them wait for each other)."""
    cores = available_cores()
    return cores if not jobs else max(1, min(int(jobs), cores))


def run_tasks(
    tasks: Sequence[tuple[Callable[[Any], Any], Any]],
    jobs: int,
    done: Callable[[int], None] | None = None,
    *,
    scheduler: str | None = None,
    note: Callable[[str], None] | None = None,
    worker_timeout: float = 60.0,
    what: str = "run",
) -> list[Any]:
    """``[fn(arg) for fn, arg in tasks]`` in the order of ``tasks``: on the Dask cluster at
    ``scheduler`` (:func:`qsls.pipeline.core.cluster.run_dask`), on ``jobs`` forked workers
    (:func:`run_pool`: stopped at once when interrupted), or in this process when
    ``jobs <= 1`` or there is a single task. ``done(i)`` is called in this process when task
    ``i`` has finished (for progress). The results are the same whichever runs them."""
    if scheduler is not None and tasks:
        return run_dask(list(tasks), scheduler, done, note, worker_timeout, what)
    results: list[Any] = [None] * len(tasks)
    if jobs <= 1 or len(tasks) <= 1:
        for i, (fn, arg) in enumerate(tasks):
            results[i] = fn(arg)
            if done is not None:
                done(i)
        return results
    for i, res in run_pool(_call, tasks, min(jobs, len(tasks))):
        results[i] = res
        if done is not None:
            done(i)
    return results


def _call(task: tuple[Callable[[Any], Any], Any]) -> Any:
    fn, arg = task
    return fn(arg)


def stop_pool(pool: Any) -> None:
    """End a process pool now: queued tasks cancelled, workers terminated (then killed)."""
    workers = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    end_processes(workers)


def end_processes(procs: Sequence[Any]) -> None:
    """Terminate ``multiprocessing`` processes, then kill those still alive after 3 s."""
    for p in procs:
        p.terminate()
    for p in procs:
        p.join(timeout=3)
        if p.is_alive():
            p.kill()
            p.join(timeout=3)
