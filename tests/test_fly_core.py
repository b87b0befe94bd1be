"""The fly stage's pure core (issue 49, docs/evaluation.md, Flying the controllers): flown
flights in, tables and findings out, with no simulator and no file; constructed flights whose
means and paired ratios are known by hand."""

from __future__ import annotations

import numpy as np
import pytest

from qsls.pipeline.fly.core import Flown, fly_tables
from qsls.pipeline.fly.estimators import FLIGHTS_FILE, PAIRED_FILE
from qsls.pipeline.fly.flights import FlyOutcome
from qsls.pipeline.fly.options import FlyOptions

SEEDS = [0, 1, 2, 3]
# controller: (tracking RMS at seed 0, ||e|| RMS, feedback command against PD's)
FLOWN = {"pd": (0.10, 0.05, 1.0), "l1_robust": (0.15, 0.04, 0.5)}


def _outcome(ctrl: str, cond: str, seed: int, estimator: str = "emulator") -> FlyOutcome:
    track, err, react = FLOWN[ctrl]
    track *= 1 + 0.01 * seed  # every controller's tracking grows alike with the seed
    metrics = {
        "duration_s": 10.0, "tracking_rms_m": track, "tracking_max_m": 2 * track,
        "perception_error_rms": err, "perception_error_max": 3 * err,
        "control_effort_rms": 1.0, "control_smoothness_rms": 0.1, "attitude_smoothness": 0.1,
        "smoothness_vs_pd": 1.0, "reaction_vs_pd": react, "error_reaction_vs_pd": 1.0,
        "attitude_diff_from_pd_rms": 0.0, "angular_rate_rms": 0.2, "blur_px_mean": 0.0,
        "crashed": False, "crash_reason": "",
    }  # fmt: skip
    x, u = np.zeros((0, 6)), np.zeros((0, 3))
    name = f"{estimator}_{cond}_s{seed}_{ctrl}"
    return FlyOutcome(name, ctrl, cond, seed, metrics, None, np.zeros(0), x, x, u, x,
                      np.zeros(0), np.zeros(0), u, extra={"lipschitz": 0.3},
                      estimator=estimator)  # fmt: skip


def _flown(estimators=("emulator",)) -> list[FlyOutcome]:
    return [
        _outcome(c, k, s, e)
        for e in estimators
        for k in ("regular", "degraded")
        for s in SEEDS
        for c in FLOWN
    ]


def test_the_core_computes_the_tables_and_findings_from_flown_flights_alone():
    t = fly_tables(Flown(_flown(), {}, [], None, {}), FlyOptions(seeds=SEEDS))  # type: ignore[arg-type]
    per = t.per.set_index(["condition", "controller"])
    # mean over seeds 0..3 of 0.10 (1 + 0.01 s) = 0.10 x 1.015
    assert per.loc[("regular", "pd"), "tracking_rms_m"] == pytest.approx(0.1015)
    assert per.loc[("degraded", "l1_robust"), "tracking_rms_m"] == pytest.approx(0.15225)
    assert per.loc[("regular", "pd"), "tracking_max_m"] == pytest.approx(0.2 * 1.03)
    assert int(per.loc[("regular", "pd"), "flights"]) == 4
    found = {f["id"]: f for f in t.findings["findings"]}
    assert found[1]["effect"] == pytest.approx(1.5)  # l1_robust tracks 1.5 x PD's, each seed
    assert found[2]["effect"] == pytest.approx(0.5)  # its feedback command half PD's
    assert found[4]["effect"] == pytest.approx(0.05 / 0.04)  # PD errs 1.25 x l1_robust
    assert 3 not in found  # no certificate, no ingested flight: no bound to test
    assert t.checks.empty and t.assumptions.empty and t.by_estimator == {}
    assert t.findings["n_seeds"] == 4
    assert "| regular | pd | 4 |" in t.markdown


def test_several_estimators_key_the_tables_and_the_primary_stays_the_stages():
    both = fly_tables(
        Flown(_flown(("camera", "emulator")), {}, [], None, {}),  # type: ignore[arg-type]
        FlyOptions(seeds=SEEDS, vio=["camera", "emulator"]),
    )
    assert set(both.analyses) == {"camera", "emulator"}
    assert len(both.flights) == 16  # the primary's flights: 2 conditions x 4 seeds x 2
    assert set(both.by_estimator[FLIGHTS_FILE]["estimator"]) == {"camera", "emulator"}
    assert len(both.by_estimator[PAIRED_FILE]) == 16  # paired by controller, condition, seed
    assert both.findings["estimator"] == "camera"
    assert set(both.findings["by_estimator"]) == {"camera", "emulator"}
    assert "## Findings per estimator" in both.markdown
