"""What every export target shares: the filter bank's taps in the exported layout, the
sizes and operation counts, the facts a generated file states, and the certificate gate.

The exported filter bank (docs/export.md#the-exported-filter-bank), with ``T`` taps::

    u[k]      = sum_{t>=1} Phi_ux(t) beta[k+1-t] + sum_{t>=0} Phi_uy(t) y[k-t]
    beta[k+1] = -sum_{t>=2} Phi_xx(t) beta[k+2-t] - sum_{t>=1} Phi_xy(t) y[k+1-t]

so the state is the last ``T`` values of ``beta`` and the last ``T + 1`` values of ``y``
(``y[k]`` included). A strictly proper controller has ``Phi_uy(0) = 0``; its tap is left out.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from qsls.pipeline.control.artifacts import Certificate, ControllerDir, check_controller_name
from qsls.pipeline.control.innovation import NO_INNOVATION, InnovationSpec
from qsls.pipeline.control.monitor import NO_MONITOR, MonitorSpec, innovation_of, monitor_of
from qsls.pipeline.control.status import CERTIFIED, EXTRAPOLATED, REFERENCE, RELAXED, UNCERTIFIED
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import NX
from qsls.pipeline.export.attitude import AttitudeLimits
from qsls.pipeline.export.innovation import state_bytes as innovation_state_bytes
from qsls.pipeline.export.statement import statement

Precision = Literal["double", "float"]
REAL_BYTES = {"double": 8, "float": 4}
INDEX_BYTES = 4
"""``unsigned int`` ring-buffer heads (two of them) and the monitor's counters."""
MONITOR_COUNTERS = 5
"""The monitor's ``unsigned int`` counters besides its ``T`` outlier flags: the window's head
and count, ticks, trips and the first trip's tick."""
REFUSAL_COUNTERS = 1
"""The step's ``unsigned int`` count of refused measurements (the latch of ``INPUT_REFUSED``)."""
Y_MAX = 1e6
"""The exported step refuses a measurement with an entry beyond ``+/- Y_MAX`` (m, m/s) or not
finite (docs/export.md#refused-measurements): far beyond any real deviation, and far inside
what the float build computes without overflow."""
INPUT_REFUSED = 4
"""The step's status bit for a refused measurement, latched until reset (beside the monitor's
``TRIP_ENVELOPE`` 1 and ``TRIP_OUTLIERS`` 2)."""

MCU_RAM_BYTES = 192 * 1024
MCU_FLASH_BYTES = 1024 * 1024
LOOP_HZ = 500.0
"""The budget the benchmark compares against: one tick of a 500 Hz flight-controller loop."""


@dataclass(frozen=True)
class ExportBank:
    """The taps as the generated code stores them (each ``(taps, rows, cols)``).

    ``uy`` = ``Phi_uy(uy_first..T)``, ``ux`` = ``Phi_ux(1..T)``, ``bb`` = ``-Phi_xx(2..T)``,
    ``by`` = ``-Phi_xy(1..T)``: ``u = sum_j ux[j] beta[k-j] + sum_j uy[j] y[k-uy_first-j]``,
    ``beta[k+1] = sum_j bb[j] beta[k-j] + sum_j by[j] y[k-j]``.
    """

    T: int
    uy_first: int
    uy: np.ndarray
    ux: np.ndarray
    bb: np.ndarray
    by: np.ndarray

    @property
    def nx(self) -> int:
        return int(self.bb.shape[1])

    @property
    def ny(self) -> int:
        return int(self.by.shape[2])

    @property
    def nu(self) -> int:
        return int(self.ux.shape[1])

    def arrays(self) -> dict[str, np.ndarray]:
        return {"uy": self.uy, "ux": self.ux, "bb": self.bb, "by": self.by}

    def constants(self) -> int:
        """Number of stored coefficients."""
        return int(sum(a.size for a in self.arrays().values()))

    def multiply_adds(self) -> int:
        """Multiply-adds per tick (dense: every stored coefficient is used once)."""
        return self.constants()


def export_bank(cdir: ControllerDir) -> ExportBank:
    """The exported layout of a filter-bank controller (refuses a static gain)."""
    c = cdir.controller
    if c.kind != "filter_bank":
        raise InputError(
            f"{cdir.folder}: '{cdir.name}' is a static gain (the PD reference), not a "
            "synthesized filter bank; export a synthesized controller"
        )
    taps = c.taps
    for name, a in taps.arrays().items():
        if not np.all(np.isfinite(a)):
            raise InputError(f"{cdir.folder}: {name} holds non-finite taps; refusing to export")
    first = 1 if c.strictly_proper else 0
    # the attitude plant's extra channels (docs/model.md) carry no measurement: the Python
    # runtime feeds them zeros (realize.pad_measurement), so the exported step, which takes
    # the 6 measured channels only, drops their columns and computes the same u
    ny = min(NX, taps.Phi_uy.shape[2])
    return ExportBank(
        T=c.T,
        uy_first=first,
        uy=np.ascontiguousarray(taps.Phi_uy[first:, :, :ny], dtype=float),
        ux=np.ascontiguousarray(taps.Phi_ux[1:], dtype=float),
        bb=np.ascontiguousarray(-taps.Phi_xx[2:], dtype=float),
        by=np.ascontiguousarray(-taps.Phi_xy[1:, :, :ny], dtype=float),
    )


@dataclass(frozen=True)
class Sizes:
    """Memory and work of one exported controller."""

    state_bytes: int
    const_bytes: int
    flops_per_tick: int
    precision: str

    def as_dict(self) -> dict[str, int | str | float]:
        return {
            "precision": self.precision,
            "state_bytes": self.state_bytes,
            "const_bytes": self.const_bytes,
            "flops_per_tick": self.flops_per_tick,
            "state_share_of_192KB_ram": self.state_bytes / MCU_RAM_BYTES,
            "const_share_of_1MB_flash": self.const_bytes / MCU_FLASH_BYTES,
        }


def sizes(
    bank: ExportBank, precision: Precision = "double", innovation: InnovationSpec = NO_INNOVATION
) -> Sizes:
    """``sizeof`` the C state struct (``T nx + (T+1) ny`` reals, two ring heads, the
    monitor's ``T + 5`` counters and the refusal count, ``unsigned int`` each, the innovation
    monitor's fields (:func:`qsls.pipeline.export.innovation.state_bytes`, a block that
    starts and ends 8-aligned), padded to the struct's alignment), the ``static const`` taps, and 2 flops per multiply-add."""
    r = REAL_BYTES[precision]
    reals = bank.T * bank.nx + (bank.T + 1) * bank.ny
    state = reals * r + (2 + MONITOR_COUNTERS + REFUSAL_COUNTERS + bank.T) * INDEX_BYTES
    inn = innovation_state_bytes(innovation, r)
    align = 8 if inn else max(r, INDEX_BYTES)  # the innovation fields start with doubles
    state += -state % align
    state += inn
    state += -state % align
    return Sizes(state, bank.constants() * r, 2 * bank.multiply_adds(), precision)


# --------------------------------------------------------------------------- facts
@dataclass(frozen=True)
class ExportFacts:
    """What a generated file states about its controller."""

    name: str
    status: str
    sha256: str
    dt: float
    mass: float
    T: int
    strictly_proper: bool
    limits: AttitudeLimits = field(default_factory=AttitudeLimits)
    """The attitude helper's tilt and thrust limits."""
    gate: float | None = None
    """Velocity gate ``V``: ``_step`` clips the velocity deviation to ``[-V, V]``."""
    monitor: MonitorSpec = NO_MONITOR
    """The onboard premise monitor's thresholds (docs/monitor.md)."""
    innovation: InnovationSpec = NO_INNOVATION
    """The innovation monitor's windows and thresholds (docs/monitor.md)."""
    statement: tuple[str, ...] = ()
    """The guarantee as the file states it, the first line naming the status
    (:mod:`qsls.pipeline.export.statement`)."""


def _shares(cert: Certificate) -> str:
    if cert.premise is None:
        return "premise shares not recorded"
    return cert.premise.shares()


def export_name(cdir: ControllerDir) -> str:
    """The name a generated file carries: the controller folder's (``.`` read as the folder it
    is), refused in one line unless it is a controller name
    (:data:`~qsls.pipeline.control.artifacts.CONTROLLER_NAME`): it reaches generated code."""
    name = cdir.name or cdir.folder.resolve().name
    # the message names no path: the folder's own name is the text refused (shown escaped)
    check_controller_name(name, "export: the controller folder's name")
    check_controller_name(cdir.certificate.controller, "export: the certificate's controller")
    return name


def facts(cdir: ControllerDir, limits: AttitudeLimits = AttitudeLimits()) -> ExportFacts:
    """What the generated files state (every text escaped where it is written: c.py, python.py)."""
    c, cert = cdir.controller, cdir.certificate
    mon = monitor_of(cdir)
    return ExportFacts(
        name=export_name(cdir),
        status=cert.status,
        sha256=cert.controller_sha256,
        dt=c.dt,
        mass=c.mass,
        T=c.T,
        strictly_proper=c.strictly_proper,
        limits=limits,
        gate=cert.gate,
        monitor=mon,
        innovation=innovation_of(cdir),
        statement=tuple(statement(cdir, mon, status_reason(cert))),
    )


# --------------------------------------------------------------------------- the gate
def status_reason(cert: Certificate) -> str:
    """Why a certificate's status is what it is, in a few words."""
    failed = [k for k, v in (cert.checks or {}).items() if not v.get("passed", True)]
    s = cert.status
    if s == CERTIFIED:
        return f"robustness_lhs = {cert.robustness_lhs:.6g} < 1, all checks passed"
    if s in (RELAXED, EXTRAPOLATED) and cert.status_reason:  # the certificate says why
        return f"{cert.status_reason}; premise on the training data: {_shares(cert)}"
    if s == RELAXED:
        return (
            "the premise is relaxed (eps_e or S set below the training data's maximum, so "
            f"part of the training data lies outside it); this is not plainly certified: {_shares(cert)}"
        )
    if s == REFERENCE:
        return "a reference controller (not synthesized), with no guarantee"
    if s == UNCERTIFIED or failed == ["robustness"]:
        return f"robustness condition fails: robustness_lhs = {cert.robustness_lhs:.6g} >= 1"
    if failed:
        return "failed checks: " + ", ".join(failed)
    return "not certified"


def check_exportable(cdir: ControllerDir, allow_uncertified: bool) -> None:
    """Refuse anything but ``certified`` unless ``allow_uncertified`` (exit 2). A gated
    certificate exports like any other: the exported step applies its gate."""
    cert = cdir.certificate
    if cert.status == CERTIFIED or allow_uncertified:
        return
    raise InputError(
        f"{cdir.folder}: status is '{cert.status}' ({status_reason(cert)}); only certified "
        "controllers are exported, pass --allow-uncertified to export it anyway"
    )
