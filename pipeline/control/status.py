"""A certificate's status: one type and its constants (no numerical imports, so a reader of
certificates, the report or the run's console, need not load the solver to name one)."""

from __future__ import annotations

from typing import Final, Literal

Status = Literal["certified", "relaxed", "uncertified", "failed", "solver_inaccurate", "reference"]
"""``certified``: every check passed, ``lhs <= 1 - margin`` and the premise holds on all the
training data; ``relaxed``: the same, but part of the training data violates the premise (or
was excluded, or S was not tested); ``uncertified``: realized and verified, but the robustness
condition fails; ``failed`` / ``solver_inaccurate``: never certified; ``reference``: not
synthesized (the PD)."""
CERTIFIED: Final[Status] = "certified"
RELAXED: Final[Status] = "relaxed"
UNCERTIFIED: Final[Status] = "uncertified"
FAILED: Final[Status] = "failed"
SOLVER_INACCURATE: Final[Status] = "solver_inaccurate"
REFERENCE: Final[Status] = "reference"
