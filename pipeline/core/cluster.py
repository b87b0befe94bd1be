"""Tasks on a Dask cluster (``dask.distributed``), for the sweep's solves and the flights of
fly and calibrate (docs/run.md#a-dask-cluster).

:func:`run_dask` submits ``fn(arg)`` for each task to the scheduler at an address and returns
the results in the order of the tasks, so a table assembled from them is the same as the
local pool's (:func:`qsls.pipeline.core.pools.run_tasks`). A worker lost mid-task is survived
(the scheduler gives its task to another worker); no worker at all, every worker gone for
``worker_timeout`` seconds, a task that kills three workers, or the scheduler itself gone are
each one line (:class:`~qsls.pipeline.core.errors.InputError`). Workers read and write the
paths the tasks name: on more than one machine they need the same filesystem.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from concurrent.futures import CancelledError
from typing import Annotated, Any

from pydantic import AfterValidator

from qsls.pipeline.core.errors import ConfigError, InputError

DASK_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx", "inproc")


def check_scheduler(address: str) -> str:
    """A Dask scheduler address ``SCHEME://HOST:PORT`` (``tcp://`` when no scheme), checked
    before anything runs: a missing port or an unknown scheme is one line, not a traceback
    after the connection timeout."""
    from distributed.comm.addressing import parse_address, parse_host_port

    example = "e.g. tcp://127.0.0.1:8786"
    try:
        scheme, loc = parse_address(address.strip())
        host, port = parse_host_port(loc)
    except ValueError as exc:
        raise ConfigError(
            f"--scheduler {address}: {exc}; expected SCHEME://HOST:PORT, {example}"
        ) from None
    if scheme not in DASK_SCHEMES:
        raise ConfigError(
            f"--scheduler {address}: unknown scheme '{scheme}' (use {', '.join(DASK_SCHEMES)}), {example}"
        )
    if not host or not 0 < int(port) < 65536:
        raise ConfigError(f"--scheduler {address}: expected SCHEME://HOST:PORT, {example}")
    return f"{scheme}://{host}:{port}"


def _checked(address: str) -> str:
    try:
        return check_scheduler(address)
    except ConfigError as exc:  # pydantic reports a ValueError as the field's error
        raise ValueError(str(exc).removeprefix("--scheduler ")) from None


SchedulerAddress = Annotated[str, AfterValidator(_checked)]
"""A Dask scheduler address as an option's type: checked (:func:`check_scheduler`) when the
options are read."""


def _n_workers(client: Any) -> int:
    return len(client.scheduler_info().get("workers", {}))


def _await_workers(client: Any, address: str, timeout: float, note: Callable[[str], None]) -> None:
    """Return once the scheduler has a worker; one line when none comes within ``timeout``."""
    if _n_workers(client):
        return
    note(f"waiting for workers at {address} (up to {timeout:g} s)")
    try:
        client.wait_for_workers(1, timeout=timeout)
    except TimeoutError:
        raise InputError(
            f"no Dask worker joined the scheduler at {address} within {timeout:g} s; "
            f"start one with 'dask worker {address}' or raise --wait-workers"
        ) from None


def run_dask(
    tasks: list[tuple[Callable[[Any], Any], Any]],
    scheduler: str,
    done: Callable[[int], None] | None = None,
    note: Callable[[str], None] | None = None,
    worker_timeout: float = 60.0,
    what: str = "run",
) -> list[Any]:
    """``[fn(arg) for fn, arg in tasks]`` on the Dask cluster at ``scheduler``, in the order
    of ``tasks``; ``done(i)`` when task ``i`` has finished, ``note`` for a waiting line. One
    line when the workers never come or all leave (their tasks would wait forever), a worker
    dies on a task three times (``KilledWorker``) or the scheduler goes away (``what`` names
    the work in that line: ``sweep``, ``fly``, ``calibration``)."""
    try:
        from distributed import Client
    except ImportError as exc:  # pragma: no cover - dask is a dependency
        raise InputError(f"--scheduler needs dask.distributed ({exc})") from None
    try:
        client = Client(scheduler, timeout="10s", set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise InputError(f"cannot reach the Dask scheduler at {scheduler} ({exc})") from None
    quiet = _quiet_dask()  # its client logs a traceback when the scheduler goes away
    try:
        return _gather_dask(
            client, tasks, scheduler, done or (lambda i: None), note or (lambda s: None),
            worker_timeout,
        )  # fmt: skip
    except (CancelledError, OSError) as exc:  # FuturesCancelledError, CommClosedError
        how = (
            f"cancelled the {what}'s tasks"
            if client.status == "running"
            else "is gone: lost the Dask scheduler"
        )
        raise InputError(
            f"the Dask scheduler at {scheduler} {how} mid-{what} ({type(exc).__name__}); "
            f"check that it is still running (or restart it and its workers) and rerun the {what}"
        ) from None
    finally:
        with contextlib.suppress(Exception):
            client.close(timeout=2)
        quiet()


def _quiet_dask() -> Callable[[], None]:
    """Silence ``distributed``'s own error logging (the lost scheduler becomes one line);
    returns what restores it."""
    import logging

    names = [
        "distributed",
        *(n for n in logging.root.manager.loggerDict if n.startswith("distributed.")),
    ]
    logs = [logging.getLogger(n) for n in names]
    levels = [log.level for log in logs]
    for log in logs:
        log.setLevel(logging.CRITICAL)

    def restore() -> None:
        for log, level in zip(logs, levels, strict=True):
            log.setLevel(level)

    return restore


def _gather_dask(
    client: Any,
    tasks: list[tuple[Callable[[Any], Any], Any]],
    scheduler: str,
    done_cb: Callable[[int], None],
    note: Callable[[str], None],
    worker_timeout: float,
) -> list[Any]:
    """The tasks' results (:func:`run_dask`'s loop: a lost scheduler raises out of it)."""
    import time

    from distributed import KilledWorker, wait

    _await_workers(client, scheduler, worker_timeout, note)
    futs = [client.submit(fn, arg, pure=False) for fn, arg in tasks]
    index = {f.key: i for i, f in enumerate(futs)}
    results: list[Any] = [None] * len(tasks)
    pending, alone_since = set(futs), None
    while pending:
        try:
            with client.as_current():  # wait() finds its client there
                done, pending = wait(pending, timeout=1.0, return_when="FIRST_COMPLETED")
        except TimeoutError:
            done = set()
        for fut in done:
            i = index[fut.key]
            try:
                results[i] = fut.result()
            except KilledWorker as exc:
                raise InputError(
                    f"Dask workers at {scheduler} died running a task ({exc}); "
                    "check the workers' memory and logs"
                ) from None
            done_cb(i)
        if done or _n_workers(client):
            alone_since = None
            continue
        alone_since = alone_since or time.monotonic()
        if time.monotonic() - alone_since > worker_timeout:
            raise InputError(
                f"every Dask worker at {scheduler} left ({len(pending)} of {len(tasks)} "
                f"tasks unfinished, none back within {worker_timeout:g} s); restart the workers"
            )
    return results
