"""Progress reporting without printing: the library calls a :class:`Progress`, the CLI draws it."""

from __future__ import annotations

from typing import Protocol


class Progress(Protocol):
    """Receives progress of long work: ``start`` a task, ``advance`` it, ``finish`` it;
    ``note`` a line worth showing meanwhile."""

    def start(self, label: str, total: float | None = None) -> None: ...

    def advance(self, amount: float = 1.0) -> None: ...

    def finish(self) -> None: ...

    def note(self, message: str) -> None:
        """One line for the user (waiting on something, a size warning), not an error."""


class NullProgress:
    """A :class:`Progress` that shows nothing (the default in the library and in tests)."""

    def start(self, label: str, total: float | None = None) -> None:
        pass

    def advance(self, amount: float = 1.0) -> None:
        pass

    def finish(self) -> None:
        pass

    def note(self, message: str) -> None:
        pass


NULL_PROGRESS = NullProgress()
