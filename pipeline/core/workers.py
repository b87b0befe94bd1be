"""Where a stage's flights run: the local process pool or a Dask cluster (docs/run.md#a-dask-cluster).

The options the stages that fly share (``qsls fly``, ``qsls calibrate``), stated once; the
pool itself is :func:`qsls.pipeline.core.pools.run_tasks`. Light: pydantic and the core only."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from pydantic import Field

from qsls.pipeline.core.cluster import SchedulerAddress
from qsls.pipeline.core.config import Options
from qsls.pipeline.core.pools import pool_size, run_tasks
from qsls.pipeline.core.progress import Progress


class PoolOptions(Options):
    """How many flights run at once, and where."""

    jobs: int = Field(0, ge=0)
    """Flights in parallel (process pool); 0 = all cores, 1 = in this process."""
    scheduler: SchedulerAddress | None = None
    """A Dask scheduler (``tcp://host:8786``): the flights run on its workers instead of the
    local pool, with the same tables (workers on other machines need this one's filesystem);
    default: none, the local pool."""
    wait_workers: float = Field(60.0, gt=0)
    """With ``scheduler``: seconds to wait for a first worker, and for one to come back after
    every worker left, before failing."""


def run_flights(
    fly: Callable[[Any], Any],
    jobs: Sequence[Any],
    pool: PoolOptions,
    progress: Progress,
    label: str,
    what: str,
) -> list[Any]:
    """``[fly(j) for j in jobs]`` in order, on the pool (at most one worker a job) or the
    pool's Dask scheduler, with a progress bar ``label``; ``what`` names the work in the
    cluster's messages."""
    progress.start(label, total=len(jobs))
    out = run_tasks(
        [(fly, j) for j in jobs], min(pool_size(pool.jobs), len(jobs)),
        lambda i: progress.advance(), scheduler=pool.scheduler, note=progress.note,
        worker_timeout=pool.wait_workers, what=what,
    )  # fmt: skip
    progress.finish()
    return out
