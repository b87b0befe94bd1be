"""One certificate ``Status``: its named constants, the report's words for each, and the
report reading ``certificate.yaml`` through ``Certificate.load`` (a status no code emits is
refused with the loader's one-line error instead of being rendered)."""

from __future__ import annotations

from typing import get_args

import pytest

from qsls.pipeline.control import status as C
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.report.facts import STATUS_WORDS, read_facts, status_words
from tests.controllerfixtures import synthesized


def test_constants_name_every_status_once_and_the_report_has_words_for_each():
    constants = [
        C.CERTIFIED,
        C.EXTRAPOLATED,
        C.RELAXED,
        C.CHOSEN,
        C.UNCERTIFIED,
        C.FAILED,
        C.SOLVER_INACCURATE,
        C.REFERENCE,
    ]
    assert sorted(constants) == sorted(get_args(C.Status))
    assert set(STATUS_WORDS) == set(get_args(C.Status))
    assert status_words(C.CERTIFIED) == ("certified", "ok")
    assert status_words(C.RELAXED) == ("relaxed premise, not certified", "warn")
    assert status_words(C.SOLVER_INACCURATE) == ("solver inaccurate", "bad")


def test_report_reads_certificates_through_the_typed_loader(tmp_path):
    cdir = synthesized(T=8)
    assert cdir.certificate.status == C.RELAXED  # the fixture's robust L1 controller, uncalibrated
    folder = tmp_path / "synth" / "l1_robust"
    cdir.certificate.save(folder)
    facts = read_facts(tmp_path, {"synth": [tmp_path / "synth"]})
    (c,) = facts.controllers
    assert (c.name, c.folder, c.status, c.certified) == ("l1_robust", "synth", C.RELAXED, False)
    assert c.cert["gamma"] == pytest.approx(cdir.certificate.gamma, rel=0, abs=0)

    f = folder / "certificate.yaml"
    f.write_text(f.read_text().replace("status: relaxed", "status: certified_maybe"))
    with pytest.raises(InputError, match=r"not a certificate of this qsls version \(status"):
        read_facts(tmp_path, {"synth": [tmp_path / "synth"]})
