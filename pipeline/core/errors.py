"""Errors the pipeline raises for bad input or impossible requests.

Every error a user can cause is a :class:`QslsError`: the CLI prints its message as one
line and exits with its ``exit_code``. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations


class QslsError(Exception):
    """A problem with the user's input or request; the message says what to do."""

    exit_code: int = 2


class InputError(QslsError):
    """A file, folder, topic or value the user gave is missing or malformed."""


class ConfigError(QslsError):
    """A configuration file or option is invalid."""


class OutputExistsError(QslsError):
    """The output folder exists and ``--force`` was not given."""


class UnwritableError(QslsError):
    """The output location cannot be written (read-only, not a folder, no permission)."""


class BusyError(QslsError):
    """Another live process is writing the same output or run folder."""


class InfeasibleError(QslsError):
    """An optimization problem has no solution; ``diagnosis`` says why."""

    exit_code = 3

    def __init__(self, message: str, diagnosis: dict | None = None) -> None:
        super().__init__(message)
        self.diagnosis = diagnosis or {}


class SolverError(QslsError):
    """The solver failed or returned an inaccurate answer."""

    exit_code = 4
