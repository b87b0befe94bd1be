"""Words a user reads (issue 50): a finding's half without seeds is said in words, never
"inconclusive: - (no seeds)"; a share nobody measured is never "~-"; the export's self-check
says what it clipped and why."""

from __future__ import annotations

import math
from pathlib import Path

from qsls.pipeline.export.stage import ExportResult
from qsls.pipeline.fly.items import NO_HALF
from qsls.pipeline.report.facts import approx_pct
from qsls.pipeline.report.summary import _half


def test_a_half_without_seeds_says_so():
    empty = {"verdict": "inconclusive", "effect": None, "ci": [None, None], "seeds": []}
    assert _half(empty) == "not tested: too few seeds to split in halves"
    full = {"verdict": "reproduced", "effect": 0.8, "ci": [0.7, 0.9], "seeds": [0, 1, 2]}
    assert _half(full).startswith("reproduced: 0.8 [") and _half(full).endswith("(seeds 0-2)")


def test_an_unmeasured_share_is_not_approximated():
    assert approx_pct(math.nan, True) == "-"
    assert approx_pct(math.nan, True, "an untested share") == "an untested share"
    assert approx_pct(0.05, True) == "~5%" and approx_pct(0.05, False) == "5%"


def test_the_export_check_says_what_it_clipped_and_why():
    r = ExportResult(
        Path("x"), "l1_robust", "certified", ["qsls_ctrl.py"],
        {"state_bytes": 1, "const_bytes": 1, "flops_per_tick": 1,
         "verify": {"max_abs_diff": 1e-12, "ticks": 200, "gate": 1.5, "clipped_ticks": 0.87}},
    )  # fmt: skip
    text = r.summary()["max |u - realization|"]
    assert "87 % of ticks had a velocity deviation clipped to it, on purpose" in text
    assert "within +-3 so the written code's clipping is compared too" in text


def test_the_quickstart_report_has_none_of_them(quickstart_session):
    work = quickstart_session[0]
    md = (work / "runs/quickstart/report/report.md").read_text()
    assert "~-" not in md and "(no seeds)" not in md and "no seeds n/a" not in md
    assert "not tested: too few seeds to split in halves" in md or NO_HALF in md
