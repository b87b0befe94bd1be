"""The files of a controller folder (one per controller inside a ``qsls synth`` output), read
together: ``controller.npz`` (:class:`~qsls.pipeline.control.controller.Controller`) and
``certificate.yaml`` (:class:`~qsls.pipeline.control.certificate.Certificate`, which records the
controller's sha256). :func:`load_controller_dir` refuses a pair whose hashes do not match, and
it, :meth:`Certificate.load` and :func:`load_runtime` recompute the certificate's numbers from
the taps (docs/verify.md). The names of both modules are re-exported here, where the stages
read a controller folder.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from qsls.pipeline.control.body import CertificateBody as CertificateBody
from qsls.pipeline.control.calibration_record import Calibration as Calibration
from qsls.pipeline.control.calibration_record import FlightEvidence as FlightEvidence
from qsls.pipeline.control.calibration_record import record_problems as record_problems
from qsls.pipeline.control.certificate import CERTIFICATE_FILE as CERTIFICATE_FILE
from qsls.pipeline.control.certificate import FILE_ORDER as FILE_ORDER
from qsls.pipeline.control.certificate import Certificate as Certificate
from qsls.pipeline.control.certificate import calibration_problems as calibration_problems
from qsls.pipeline.control.certificate import differs as differs
from qsls.pipeline.control.certificate import parse_certificate, verified_controller
from qsls.pipeline.control.certificate import recomputation_problems as recomputation_problems
from qsls.pipeline.control.certificate import recomputed_body as recomputed_body
from qsls.pipeline.control.certificate import record_consistency as record_consistency
from qsls.pipeline.control.controller import CONTROLLER_FILE as CONTROLLER_FILE
from qsls.pipeline.control.controller import CONTROLLER_NAME as CONTROLLER_NAME
from qsls.pipeline.control.controller import Controller
from qsls.pipeline.control.controller import check_controller_name as check_controller_name
from qsls.pipeline.control.controller import name_problem as name_problem
from qsls.pipeline.control.realize import RealizedController, StaticGainController
from qsls.pipeline.core.errors import InputError


@dataclass(frozen=True)
class ControllerDir:
    """A controller folder: its controller, its certificate, verified to belong together."""

    folder: Path
    controller: Controller
    certificate: Certificate

    @property
    def name(self) -> str:
        return self.folder.name


def load_controller_dir(folder: Path) -> ControllerDir:
    """Both files of ``folder`` (a ``controller.npz`` path is taken as its folder); refuses a
    controller whose sha256 is not the one its certificate records, whose gains do not match
    its taps, or whose certificate's numbers are not what its taps and premise give
    (:func:`recomputation_problems`), each in one line."""
    folder = Path(folder)
    if folder.is_file() and folder.name == CONTROLLER_FILE:
        folder = folder.parent
    if not folder.is_dir():
        raise InputError(f"{folder}: no such controller folder")
    cert, digest = parse_certificate(folder / CERTIFICATE_FILE)
    ctrl = verified_controller(folder, cert, digest)
    assert ctrl is not None
    return ControllerDir(folder, ctrl, cert)


def load_runtime(folder: Path) -> RealizedController | StaticGainController:
    """The verified controller of ``folder`` as a runtime (``reset()``, ``step(y) -> u``)."""
    d = load_controller_dir(folder)
    cert = d.certificate.model_dump()
    c = d.controller
    if c.kind == "static_gain":
        assert c.K is not None
        return StaticGainController(c.K, c.dt, certificate=cert, name=d.name)
    return RealizedController(
        c.bank, c.dt, certificate=cert, strictly_proper=c.strictly_proper, name=d.name
    )
