"""A certificate's status: one type and its constants (no numerical imports, so a reader of
certificates, the report or the run's console, need not load the solver to name one)."""

from __future__ import annotations

from typing import Final, Literal

Status = Literal[
    "certified",
    "extrapolated",
    "relaxed",
    "chosen",
    "uncertified",
    "failed",
    "solver_inaccurate",
    "reference",
]
"""``certified``: a calibrated premise (docs/calibration.md: at least 19 calibration flights
flown by the controller itself, ``alpha <= 0.1``) under which every check passed, the
condition holds with the taps fixed, and the calibration flights reached ``rho*``;
``extrapolated``: the same, but ``rho*`` lies beyond the distances the calibration flights
reached; ``relaxed``: every check passed under a premise that is not calibrated for the next
flight (the design premise of ``qsls synth``, or a percentile one, or too few calibration
flights), the certificate's ``status_reason`` says which; ``chosen``: every check passed
under a premise whose S was picked by hand the way the paper did (the paper mode,
docs/paper.md), not measured: nothing is claimed for any flight; ``uncertified``: realized and verified, but the robustness
condition fails; ``failed`` / ``solver_inaccurate``: never certified; ``reference``: not
synthesized (the PD)."""
CERTIFIED: Final[Status] = "certified"
EXTRAPOLATED: Final[Status] = "extrapolated"
RELAXED: Final[Status] = "relaxed"
CHOSEN: Final[Status] = "chosen"
UNCERTIFIED: Final[Status] = "uncertified"
FAILED: Final[Status] = "failed"
SOLVER_INACCURATE: Final[Status] = "solver_inaccurate"
REFERENCE: Final[Status] = "reference"
