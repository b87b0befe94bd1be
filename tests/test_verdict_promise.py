"""Each controller's verdict leads with one plain sentence: what its certificate promises,
for which conditions, with which probability, and what lies outside (evaluate/verdict.py
``promise``; the console, the report's cards and evaluation.json)."""

from __future__ import annotations

import json

import pytest
import yaml

from qsls.pipeline.evaluate.options import EvaluateOptions
from qsls.pipeline.evaluate.stage import evaluate
from qsls.pipeline.evaluate.verdict import controller_promises, promise, read_verdicts
from tests.test_evaluate_weighted import weighted  # noqa: F401  (the fixture)

CERTIFIED_CERT = {
    "controller": "l1_robust", "status": "certified", "robust": True, "rho_star": 1.2089,
    "gamma": 0.13539, "tested_range": 1.49,
    "calibration": {
        "flights": 20, "alpha": 0.1, "method": "conformal", "confidence": None,
        "duration_s": 15.0,
        "conditions": {"perception": "regular", "estimator": "emulator",
                       "reference": {"kind": "circle", "radius": 1.0},
                       "vehicle": {"mass": 0.256}},
    },
}  # fmt: skip


def test_a_certified_certificate_states_probability_conditions_bounds_and_outside():
    text = promise(CERTIFIED_CERT)
    assert text == (
        "With probability at least 0.9, a next 15 s flight of l1_robust in the conditions it "
        "was calibrated in (regular perception, the emulator estimator, the circle reference "
        "of radius 1 m, the 0.256 kg vehicle) keeps its premise and then stays within rho* = "
        "1.21 of the training states, its dense perception error within gamma = 0.135; a "
        "flight in other conditions (another perception, estimator, reference or vehicle) "
        "lies outside this promise."
    )
    pac = {**CERTIFIED_CERT, "calibration": {**CERTIFIED_CERT["calibration"], "alpha": 0.05,
                                               "method": "pac", "confidence": 0.95}}  # fmt: skip
    assert promise(pac).startswith(
        "With probability at least 0.95, with confidence 0.95 over the calibration draw, a next"
    )


@pytest.mark.parametrize(
    ("cert", "expected"),
    [
        ({"controller": "pd", "status": "reference"},
         "pd is the reference controller: it promises nothing, it is measured."),
        ({"controller": "l1_robust", "status": "relaxed",
          "status_reason": "not calibrated: the premise describes the design flights only; x"},
         "l1_robust promises nothing for a next flight (relaxed: not calibrated: the premise "
         "describes the design flights only); calibrating it on flights it flies itself (qsls "
         "calibrate) can certify it."),
        ({"controller": "l1_robust", "status": "extrapolated", "tested_range": 0.8,
          "rho_star": 1.2},
         "l1_robust promises nothing yet (extrapolated: its calibration flights reached 0.8 "
         "from the training states, short of the rho* = 1.2 its claim needs); range flights "
         "that reach rho* would certify it."),
        ({"controller": "l1_nominal", "status": "uncertified", "robust": False},
         "l1_nominal promises nothing: it was designed without the robustness constraint."),
        ({"controller": "x", "status": "failed", "status_reason": "realization 1e-3"},
         "x promises nothing: its checks failed (realization 1e-3)."),
        # a certified status without the calibration that backs it promises nothing
        ({"controller": "y", "status": "certified"}, "y promises nothing (certified)."),
    ],
)  # fmt: skip
def test_what_is_not_certified_promises_nothing_and_says_why(cert, expected):
    assert promise(cert) == expected


def test_one_sentence_per_condition_once():
    degraded = {
        **CERTIFIED_CERT,
        "calibration": {
            **CERTIFIED_CERT["calibration"],
            "conditions": {**CERTIFIED_CERT["calibration"]["conditions"], "perception": "degraded"},
        },
    }
    got = controller_promises(
        [("l1_robust", CERTIFIED_CERT), ("l1_robust", degraded), ("l1_robust", CERTIFIED_CERT)]
    )  # fmt: skip
    text = got["l1_robust"]
    assert text.count("With probability") == 2
    assert text.index("(regular perception") < text.index("(degraded perception")


def test_the_evaluation_leads_each_verdict_with_its_promise(weighted, tmp_path):  # noqa: F811
    _, model, ctrl, flight, _, _ = weighted
    res = evaluate([flight], model, [ctrl], EvaluateOptions(figures=False), tmp_path / "ev")
    cert = yaml.safe_load((ctrl / "certificate.yaml").read_text())
    doc = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert doc["promises"] == {"l1_robust": promise(cert)}
    (v,) = read_verdicts(tmp_path / "ev")
    assert v.lines() == [promise(cert), v.line()]
    assert [x.lines() for x in res.verdicts()] == [v.lines()]
    assert v.lines()[0].startswith("l1_robust promises nothing for a next flight (relaxed: not")


def test_the_quickstart_console_and_report_lead_with_the_promise(quickstart_session):
    work, _, proc, _, _ = quickstart_session
    out = proc.stdout
    flown = out[out.index("Certified bound on the flown flights:") :]
    lines = [ln.strip() for ln in flown.splitlines()[1:]]
    k = next(i for i, ln in enumerate(lines) if ln.startswith("l1_robust:"))
    assert lines[k - 1].startswith("With probability at least 0.9, a next 15 s flight of l1_robust")
    assert "regular perception" in lines[k - 1] and "outside this promise" in lines[k - 1]
    page = (work / "runs/quickstart/report/index.html").read_text()
    card = page[page.index("<h3>l1_robust</h3>") :]
    card = card[: card.index("</div>")]
    assert card.index('<p class="promise">With probability at least 0.9') < card.index("<dl>")
    md = (work / "runs/quickstart/report/report.md").read_text()
    assert "- **l1_robust**: With probability at least 0.9" in md
    # certificate.yaml states it too, right after its status (written by qsls calibrate)
    f = work / "runs/quickstart/calibrate/regular/l1_robust/certificate.yaml"
    cert = yaml.safe_load(f.read_text())
    assert cert["promise"] == promise(cert) == lines[k - 1]
    assert list(cert)[:4] == ["controller", "status", "status_reason", "promise"]
