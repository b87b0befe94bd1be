"""What every command shares: one-line errors, progress bars, summary tables, overrides."""

from __future__ import annotations

import contextlib
import functools
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterable, Mapping
from typing import Any, TypeVar

import typer

F = TypeVar("F", bound=Callable[..., Any])


class Terminated(KeyboardInterrupt):
    """SIGTERM (what ``timeout``, SLURM and CI send), unwound like Ctrl-C: every
    ``StageWriter`` removes its temporary folder on the way out."""


_MAIN_PID = 0


def _end_children() -> None:
    """End this process's worker processes (process pools): terminate, then kill."""
    import multiprocessing

    from qsls.pipeline.core.pools import end_processes

    end_processes(multiprocessing.active_children())


def _die_with_parent() -> None:
    """In a forked worker: be killed when the qsls process dies, even by SIGKILL (Linux
    ``PR_SET_PDEATHSIG``), so no worker outlives a killed run."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        return
    if os.getppid() != _MAIN_PID:  # the parent died before the call above
        os._exit(1)


def _exit_now(code: int) -> None:
    """Leave at once, the unwinding done (every ``StageWriter`` has removed its temporary
    folder, the workers are ended): release the locks, flush, ``os._exit``. A normal exit
    would join the process pool's manager thread, which may be blocked reading a large result
    from a worker that was just terminated: the run then never exited (issue 50)."""
    from qsls.pipeline.core.locks import release_all

    release_all()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(code)


def _on_sigterm(signum: int, frame: Any) -> None:
    if os.getpid() != _MAIN_PID:  # a forked worker inherited the handler: die as asked
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    _end_children()
    raise Terminated


def cli_errors(fn: F) -> F:
    """Turn the pipeline's user errors into ``error: ...`` on stderr and their exit code;
    SIGTERM and Ctrl-C end the worker processes and keep no partial output."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        from qsls.pipeline.core.config import forget_config_files
        from qsls.pipeline.core.errors import QslsError

        forget_config_files()
        global _MAIN_PID
        if not _MAIN_PID and sys.platform.startswith("linux"):
            os.register_at_fork(after_in_child=_die_with_parent)
        _MAIN_PID = os.getpid()
        main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGTERM, _on_sigterm) if main else None
        try:
            return fn(*args, **kwargs)
        except QslsError as exc:
            msg = " ".join(str(exc).split("\n"))
            typer.echo(f"error: {msg}", err=True)
            raise typer.Exit(exc.exit_code) from None
        except OSError as exc:  # a full disk, anywhere a stage writes (its temporaries go)
            from qsls.pipeline.core.locks import FULL, full_message

            if exc.errno not in FULL:
                raise
            typer.echo(f"error: {full_message(exc)}", err=True)
            raise typer.Exit(2) from None
        except KeyboardInterrupt as exc:
            _end_children()
            what = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
            typer.echo(f"error: {what}; no partial output was kept", err=True)
            code = 143 if isinstance(exc, Terminated) else 130
            if main and os.getpid() == _MAIN_PID:
                _exit_now(code)
            raise typer.Exit(code) from None
        finally:
            from qsls.pipeline.core.locks import release_all

            release_all()
            if main:
                signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)

    return wrapper  # type: ignore[return-value]


def number_or_name(value: str | None) -> float | str | None:
    """A value that is a number or an error-model name (``max``, ``p95``)."""
    if value is None:
        return None
    try:
        return float(value)
    except ValueError:
        return value.strip()


def parse_list(text: str | None, what: str, kind: str = "float") -> list[Any] | None:
    """The one parser of comma-separated command-line lists: ``"1, 2,3"`` -> ``[1.0, 2.0, 3.0]``.

    ``kind``: ``float``, ``int``, or ``value`` (a number, ``true``/``false``, or an
    error-model name such as ``p95``). ``None`` (not given) stays ``None``; a bad item is a
    one-line :class:`ConfigError` naming the option."""
    if text is None:
        return None
    from qsls.pipeline.core.errors import ConfigError

    out: list[Any] = []
    for item in (x.strip() for x in text.split(",") if x.strip()):
        try:
            if kind == "int":
                out.append(int(item))
            elif kind == "float":
                out.append(float(item))
            elif item.lower() in ("true", "false"):
                out.append(item.lower() == "true")
            else:
                out.append(number_or_name(item))
        except ValueError:
            raise ConfigError(
                f"{what}: '{item}' is not {'an integer' if kind == 'int' else 'a number'} "
                f"(expected comma-separated {'integers' if kind == 'int' else 'numbers'}, "
                f"got '{text}')"
            ) from None
    if not out:  # "--seeds ''" would silently mean the default
        raise ConfigError(
            f"{what}: empty list; give comma-separated "
            f"{'integers' if kind == 'int' else 'values'}, or leave the option out for the default"
        )
    return out


def overrides(**kwargs: Any) -> dict[str, Any]:
    """The options given on the command line (``None`` means not given)."""
    return {k: v for k, v in kwargs.items() if v is not None}


class RichProgress:
    """A :class:`qsls.pipeline.core.progress.Progress` drawn with rich on stderr.

    When stderr is not a terminal (a log file, CI, a pipe) no bar is drawn; instead a task
    prints ``LABEL: DONE/TOTAL (ELAPSED s)`` at most every ``every`` seconds while it
    advances, so a long stage (fly: 24 s) is not silent until it ends (a short one stays
    quiet). rich is loaded only to draw bars (25-35 ms of a command's start)."""

    def __init__(self, every: float = 5.0) -> None:
        self._console: Any = None
        self._progress: Any = None
        if sys.stderr.isatty():
            from rich.console import Console

            self._console = Console(stderr=True)
            self._progress = _bars(self._console)
        self._task: Any = None
        self._every = every
        self._label, self._done = "", 0.0
        self._total: float | None = None
        self._t0 = self._last = 0.0

    def _line(self) -> None:
        import time

        now = time.perf_counter()
        self._last = now
        total = f"/{self._total:g}" if self._total is not None else ""
        self.note(f"{self._label}: {self._done:g}{total} ({now - self._t0:.1f} s)")

    def __enter__(self) -> RichProgress:
        if self._progress is not None:
            self._progress.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._progress is not None:
            self._progress.stop()

    def start(self, label: str, total: float | None = None) -> None:
        import time

        if self._progress is not None:
            self._task = self._progress.add_task(label, total=total)
        else:
            self._task = label
            self._label, self._total, self._done = label, total, 0.0
            self._t0 = self._last = time.perf_counter()

    def advance(self, amount: float = 1.0) -> None:
        import time

        if self._task is None:
            return
        if self._progress is not None:
            self._progress.advance(self._task, amount)
            return
        self._done += amount
        if time.perf_counter() - self._last >= self._every:
            self._line()

    def note(self, message: str) -> None:
        """A line on stderr, shown also when no bar is drawn (not a terminal); through the
        bars' console where they are drawn, so lines and bars do not mix."""
        if self._console is None:
            print(message, file=sys.stderr, flush=True)
        else:
            self._console.print(message, soft_wrap=True, markup=False, highlight=False)

    def finish(self) -> None:
        if self._task is not None and self._progress is not None:
            task = self._progress.tasks[-1]
            if task.total is not None:
                self._progress.update(self._task, completed=task.total)
        self._task = None


def _bars(console: Any) -> Any:
    """rich's live progress bars on ``console``: description, bar, done/total, times."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=False,
    )


def print_summary(title: str, rows: Iterable[tuple[str, Any]] | Mapping[str, Any]) -> None:
    """A two-column table on stdout."""
    items = rows.items() if isinstance(rows, Mapping) else rows
    cells = [[str(k), _fmt(v)] for k, v in items]
    typer.echo(box_table(title, None, cells, ascii_only=not _unicode_stdout()))


def print_verdicts(title: str, verdicts: Iterable[Any]) -> None:
    """The answer last: per controller what its certificate promises, then ``holds`` /
    ``FAILS`` and the worst ratio (``verdicts``: Verdicts, or their lines as recorded in a
    run state)."""
    lines = [x for v in verdicts for x in ([v] if isinstance(v, str) else v.lines())]
    if lines:
        typer.echo(f"{title}:")
        for line in lines:
            typer.echo(f"  {line}")


def print_table(title: str, columns: list[str], rows: Iterable[Iterable[Any]]) -> None:
    """A table with a header row on stdout."""
    cells = [[_fmt(v) for v in r] for r in rows]
    typer.echo(box_table(title, columns, cells, ascii_only=not _unicode_stdout()))


# ascii_only: (top, header rule, body bar, header bar, bottom, header top); each rule is
# left, fill, mid, right
_BOXES = {
    False: ("┌─┬┐", "┡━╇┩", "│", "┃", "└─┴┘", "┏━┳┓"),
    True: ("+-++", "+=++", "|", "|", "+-++", "+-++"),
}


def _unicode_stdout() -> bool:
    """Whether stdout's encoding has the box characters (a Latin-1 terminal has not)."""
    try:
        "".join(_BOXES[False]).encode(sys.stdout.encoding or "ascii")
    except (UnicodeEncodeError, LookupError):
        return False
    return True


def _width(text: str) -> int:
    """Columns ``text`` takes on a terminal: wide East Asian characters two, combining
    marks none."""
    import unicodedata

    return sum(
        0 if unicodedata.combining(ch) else 2 if unicodedata.east_asian_width(ch) in "WF" else 1
        for ch in text
    )


def box_table(
    title: str, header: list[str] | None, rows: list[list[str]], *, ascii_only: bool = False
) -> str:
    """``rows`` (and ``header``) in a box drawn as rich draws its tables (``+-|`` with
    ``ascii_only``), the title above, a cell's lines one below the other. Every column is as
    wide as its widest cell: a log or a pipe gets whole lines, not rich's cells wrapped to
    80 columns, and a command does not load rich (25 ms of its start) to print its
    summary."""
    top, head_rule, bar, head_bar, bottom, head_top = _BOXES[ascii_only]
    cells = [[c.splitlines() or [""] for c in r] for r in ([header] if header else []) + rows]
    ncol = max((len(r) for r in cells), default=0)
    width = [max((_width(x) for r in cells for x in r[j]), default=0) for j in range(ncol)]

    def rule(chars: str) -> str:
        return chars[0] + chars[2].join(chars[1] * (w + 2) for w in width) + chars[3]

    def line(row: list[list[str]], sep: str) -> list[str]:
        row = row + [[""]] * (ncol - len(row))
        out = []
        for i in range(max(len(c) for c in row)):
            texts = [c[i] if i < len(c) else "" for c in row]
            padded = (f" {x}{' ' * (w - _width(x))} " for x, w in zip(texts, width, strict=True))
            out.append(sep + sep.join(padded) + sep)
        return out

    out = [title]
    if header:
        out += [rule(head_top), *line(cells[0], head_bar), rule(head_rule)]
        body = cells[1:]
    else:
        out.append(rule(top))
        body = cells
    for r in body:
        out += line(r, bar)
    out.append(rule(bottom))
    return "\n".join(out)


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)
