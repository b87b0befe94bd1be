"""Issue 47, cause 4: a certificate's numbers are recomputed on load and from its evidence
(docs/verify.md). Each tampering the audit found is refused on load (one line naming the field,
the stored and the recomputed value) or by ``qsls verify``; the quickstart's own output loads
and verifies."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from qsls.pipeline.calibrate.verify import verify
from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    CONTROLLER_FILE,
    Certificate,
    load_controller_dir,
)
from qsls.pipeline.core.errors import InputError


@pytest.fixture(scope="module")
def calib(quickstart_session, tmp_path_factory) -> Path:
    """A copy of the quickstart's calibration output (certified ``l1_robust`` with its tick
    logs) and its synth folder beside it."""
    run = quickstart_session[0] / "runs" / "quickstart"
    out = tmp_path_factory.mktemp("tamper")
    shutil.copytree(run / "calibrate", out / "calibrate")
    shutil.copytree(run / "synth", out / "synth")
    return out


def _copy(calib: Path, tmp_path: Path) -> Path:
    shutil.copytree(calib / "calibrate", tmp_path / "calibrate")
    return tmp_path / "calibrate"


def _edit(folder: Path, edit) -> None:
    f = folder / CERTIFICATE_FILE
    data = yaml.safe_load(f.read_text())
    edit(data)
    f.write_text(yaml.safe_dump(data, sort_keys=False))


def _refused(folder: Path) -> str:
    with pytest.raises(InputError) as exc:
        load_controller_dir(folder)
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_the_quickstart_output_loads_and_verifies(calib):
    """Every stored number is what the taps give (rel 1e-9), and the evidence gives the record:
    20 calibration, 20 range and 20 validation tick logs re-read."""
    d = load_controller_dir(calib / "calibrate" / "regular" / "l1_robust")
    assert d.certificate.status == "certified"
    ev = d.certificate.calibration.evidence
    assert [e.role for e in ev].count("calibration") == d.certificate.calibration.flights
    r = verify(calib / "calibrate")
    assert r.verified, r.lines()
    assert r.flights == len(ev) and r.flights >= 40
    for f in ("l1_robust", "l1_nominal", "pd", "l1_robust_imitation"):
        load_controller_dir(calib / "synth" / f)


@pytest.mark.parametrize(
    ("field", "value"),
    [("rho_star", 0.9), ("a", 0.5), ("gamma", 263.0), ("gamma", float("nan")), ("norm_N", 2.0)],
)
def test_an_edited_theorem_number_is_refused_on_load(calib, tmp_path, field, value):
    folder = tmp_path / "l1_robust"
    shutil.copytree(calib / "calibrate" / "regular" / "l1_robust", folder)
    stored = yaml.safe_load((folder / CERTIFICATE_FILE).read_text())[field]
    _edit(folder, lambda d: d.__setitem__(field, value))
    msg = _refused(folder)
    assert f"{field} stored {value:.10g}, recomputed {stored:.10g}" in msg, msg
    with pytest.raises(InputError):  # the certificate alone, beside its taps, too
        Certificate.load(folder)


def test_another_controllers_taps_with_their_hash_are_refused(calib, tmp_path):
    """l1_nominal's controller.npz in the certified folder, sha256 updated: its taps give
    another robustness_lhs and rho* (beyond r), so the file is refused."""
    import hashlib

    folder = tmp_path / "l1_robust"
    shutil.copytree(calib / "calibrate" / "regular" / "l1_robust", folder)
    nominal = (calib / "synth" / "l1_nominal" / CONTROLLER_FILE).read_bytes()
    (folder / CONTROLLER_FILE).write_bytes(nominal)
    _edit(folder, lambda d: d.__setitem__("controller_sha256", hashlib.sha256(nominal).hexdigest()))
    msg = _refused(folder)
    assert "norm_phi_xx_h stored" in msg and "more" in msg
    cert = Certificate.model_validate(yaml.safe_load((folder / CERTIFICATE_FILE).read_text()))
    assert cert.rho_star < cert.radius  # the claim the foreign taps cannot back


@pytest.mark.parametrize(
    ("edit", "why"),
    [
        (lambda d: d.__setitem__("tested_range", float("nan")), "tested_range"),
        (lambda d: d["calibration"].__setitem__("tested_range", float("nan")), "tested_range"),
        (lambda d: d.__setitem__("checks", None), "checks.solver stored none"),
        (lambda d: d["checks"]["realization"].__setitem__("passed", "false"), "passed is 'false'"),
        (lambda d: d["calibration"].__setitem__("duration_s", 60.0), "duration_s 60"),
        (lambda d: d.__setitem__("tested_range", 2.0), "tested_range stored 2.0, the record's"),
    ],
)
def test_a_record_or_check_edit_is_refused_on_load(calib, tmp_path, edit, why):
    folder = tmp_path / "l1_robust"
    shutil.copytree(calib / "calibrate" / "regular" / "l1_robust", folder)
    _edit(folder, edit)
    assert why in _refused(folder)


def test_an_extrapolated_certificate_relabelled_certified_is_refused(calib, tmp_path):
    """The record says the flights reached 0.136 (< rho*): a top-level status and tested_range
    edited to 'certified' and 1.3 disagree with it."""
    folder = tmp_path / "l1_robust"
    shutil.copytree(calib / "calibrate" / "regular" / "l1_robust", folder)

    def edit(d):
        d["calibration"]["tested_range"] = 0.136
        d["tested_range"] = 1.3
        d["status"] = "certified"

    _edit(folder, edit)
    msg = _refused(folder)
    assert "tested to 1.3" in msg or "tested_range stored 1.3, the record's 0.136" in msg


def test_verify_recomputes_what_a_consistent_edit_hides(calib, tmp_path):
    """Edits consistent on their face load, but the tick logs say otherwise: a relabelled
    perception condition, a longer duration (record and conditions), a range tested further
    (both tested ranges), a missing and an altered tick log; exit 1 with one line each."""
    out = _copy(calib, tmp_path)
    folder = out / "regular" / "l1_robust"

    def edit(d):
        d["calibration"]["conditions"]["perception"] = "degraded"
        d["calibration"]["conditions"]["duration_s"] = 60.0
        d["calibration"]["duration_s"] = 60.0

    _edit(folder, edit)
    load_controller_dir(folder)  # consistent on its face
    ev = Certificate.load(folder).calibration.evidence
    (out / ev[0].ticks).unlink()
    with open(out / ev[1].ticks, "ab") as fh:
        fh.write(b"\0")
    r = verify(out)
    text = "\n".join(r.lines())
    assert not r.verified
    assert "conditions.perception" in text and "stored degraded, recomputed regular" in text
    assert "calibration.duration_s: stored 60, recomputed 15" in text
    assert f"{ev[0].flight} tick log: stored {ev[0].ticks}, recomputed missing" in text
    assert f"{ev[1].flight} tick log sha256" in text
    proc = subprocess.run([sys.executable, "-m", "qsls.cli.main", "verify", str(out)],
                          capture_output=True, text=True)  # fmt: skip
    assert proc.returncode == 1 and proc.stdout.count("\n") == len(r.differences)


def test_verify_recomputes_the_scores_and_the_tested_range(calib, tmp_path):
    """A score and the tested range edited consistently with the quantile and each other (so
    the file loads) are recomputed from the tick logs: the calibration's own scoring."""
    out = _copy(calib, tmp_path)
    folder = out / "regular" / "l1_robust"
    cert = Certificate.load(folder)
    c = cert.calibration
    low = sorted(range(len(c.scores)), key=lambda i: c.scores[i])[0]

    def edit(d):
        d["calibration"]["scores"][low] = c.scores[low] / 2  # below the quantile: lambda_hat stays
        d["calibration"]["tested_range"] = c.tested_range * 1.5
        d["tested_range"] = c.tested_range * 1.5

    _edit(folder, edit)
    load_controller_dir(folder)
    text = "\n".join(verify(out).lines())
    assert (
        f"calibration.scores[{low}]: stored {c.scores[low] / 2:.10g}, recomputed {c.scores[low]:.10g}"
        in text
    )
    assert f"calibration.tested_range: stored {c.tested_range * 1.5:.10g}" in text
    proc = subprocess.run([sys.executable, "-m", "qsls.cli.main", "verify", str(calib / "calibrate")],
                          capture_output=True, text=True)  # fmt: skip
    assert proc.returncode == 0 and proc.stdout.startswith("verified:"), proc.stdout + proc.stderr
