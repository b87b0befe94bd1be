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
