"""The innovation monitor's calibrated mode (issue 48, docs/monitor.md#the-calibrated-mode) on
the quickstart's calibration: each calibration flight's statistic and their conformal quantile
against an independent numpy recomputation from the kept tick logs; the calibrated thresholds
strictly below the sound ones, a validation flight tripping them exactly when its statistic
exceeds the quantile, their false trips within the stated rate; the record written by
calibrate's own step, refused when edited, recomputed by verify."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from qsls.pipeline.control.artifacts import CERTIFICATE_FILE, load_controller_dir
from qsls.pipeline.control.innovation import (
    QUANTUM_MAX,
    QUANTUM_SCALE,
    calibrated_innovation,
    flight_statistic,
    innovation_flags,
)
from qsls.pipeline.control.monitor import (
    hover_input,
    innovation_of,
    monitor_of,
    sound_innovation_of,
)
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import GRAVITY, NX
from qsls.pipeline.core.ticks import TickLog
from qsls.pipeline.premise.honest import clopper_pearson

RATE = 0.1


@pytest.fixture(scope="module")
def calib(quickstart_session, tmp_path_factory) -> Path:
    """A copy of the quickstart's calibration output (its config keeps the sound mode: the
    record holds the statistics and the quantile at the default rate 0.1)."""
    run = quickstart_session[0] / "runs" / "quickstart"
    out = tmp_path_factory.mktemp("calmon") / "calibrate"
    shutil.copytree(run / "calibrate", out)
    return out


def _folder(calib: Path) -> Path:
    return calib / "regular" / "l1_robust"


def _logs(calib: Path, role: str) -> list[tuple[str, TickLog]]:
    d = load_controller_dir(_folder(calib))
    assert d.certificate.calibration is not None
    return [
        (e.flight, TickLog.read(calib / e.ticks))
        for e in d.certificate.calibration.evidence
        if e.role == role
    ]


def independent_statistic(spec, log: TickLog, mass: float, gate: float) -> float:
    """The statistic written from the definition with numpy, not the onboard monitor's
    running sums: ``nu_k = y'_{k+1} - A_xx y'_k - A_xa a_k - B_x du_k`` (``a_{k+1} = A_aa a_k +
    B_a du_k`` from 0), truncated to quanta of 2^-30, window sums by cumulative sums, the median
    over ``ns`` consecutive end ticks, its largest ``|median| / threshold`` over the flight."""
    y = np.asarray(log.y) - np.asarray(log.ref)
    y[:, 3:] = np.clip(y[:, 3:], -gate, gate)
    du = np.asarray(log.u) - np.asarray(log.uff) - np.array([0.0, 0.0, mass * GRAVITY])
    a_xx, a_xa, b_x = (np.array(m, dtype=float) for m in (spec.a_xx, spec.a_xa, spec.b_x))
    a_aa, b_a = np.array(spec.a_aa, dtype=float), np.array(spec.b_a, dtype=float)
    n = len(y)
    a = np.zeros((n, len(a_aa)))
    for k in range(n - 1):
        a[k + 1] = a_aa @ a[k] + b_a @ du[k]
    nu = y[1:] - y[:-1] @ a_xx.T - du[:-1] @ b_x.T
    if len(a_aa):
        nu = nu - a[:-1] @ a_xa.T
    q = np.trunc(np.clip(nu * QUANTUM_SCALE, -QUANTUM_MAX, QUANTUM_MAX))
    csum = np.vstack([np.zeros(NX), np.cumsum(q, axis=0)])
    worst = 0.0
    for w, K in enumerate(spec.windows):
        sums = csum[K:] - csum[:-K]  # sums[j]: innovations j .. j + K - 1
        for c in range(NX):
            thr = spec.threshold[w][c]
            if thr <= 0:
                continue
            ns = spec.shifts[c]
            for j in range(ns - 1, len(sums)):
                med = np.median(sums[j - ns + 1 : j + 1, c])
                worst = max(worst, abs(med) / QUANTUM_SCALE / thr)
    return worst


def test_the_quantile_is_the_independent_recomputations(calib):
    """The record's statistics are the numpy definition's on each calibration flight's tick
    log (1e-9 relative: the innovation's own roundings may move a truncation by one quantum),
    its rank ceil(21 x 0.9) = 19 and its quantile the 19th smallest; the quickstart keeps the
    sound mode, so its monitor flies the sound thresholds."""
    d = load_controller_dir(_folder(calib))
    rec = d.certificate.calibration.monitor
    assert rec is not None and rec.mode == "sound" and rec.false_trip_rate == RATE
    spec = sound_innovation_of(d)
    assert spec.active and innovation_of(d) == spec
    logs = _logs(calib, "calibration")
    want = [
        independent_statistic(spec, lg, d.controller.model.mass, d.certificate.gate)
        for _, lg in logs
    ]
    assert len(want) == len(rec.statistics) == 20
    np.testing.assert_allclose(rec.statistics, want, rtol=1e-9)
    assert rec.rank == 19 == math.ceil(21 * (1 - RATE))
    assert rec.quantile == pytest.approx(sorted(want)[18], rel=1e-9)
    # the quickstart's flights hold their premise: every statistic below the sound bound
    assert min(want) > 0.1 and max(want) < 1.0


def test_calibrated_thresholds_are_below_the_sound_ones_and_trip_only_beyond_the_quantile(calib):
    """Calibrated at rate 0.1 the window thresholds are q < 1 times the sound ones, strictly
    below on every checked window and channel; on the certificate's own 20 validation flights
    the calibrated monitor trips exactly where a flight's statistic exceeds q (the onboard bits
    from the logs), the sound one never, and the share that trips is within the stated rate
    (its Clopper-Pearson interval reaches 0.1; measured: 2 of 20 on the quickstart of
    07169ed, 3 of 20 on its family of issue 47, each a flight whose premise held)."""
    d = load_controller_dir(_folder(calib))
    rec = d.certificate.calibration.monitor
    sound = sound_innovation_of(d)
    spec = calibrated_innovation(sound, rec.model_copy(update={"mode": "calibrated"}))
    assert spec.mode == "calibrated" and spec.false_trip_rate == RATE
    assert 0.3 < spec.scale < 1.0 and spec.scale == pytest.approx(rec.quantile, rel=2e-9)
    live = [(w, c) for w, row in enumerate(sound.threshold) for c, v in enumerate(row) if v > 0]
    assert live and all(spec.threshold[w][c] < sound.threshold[w][c] for w, c in live)
    assert spec.outlier_threshold == sound.outlier_threshold  # the outlier count stays sound
    valid = pd.read_parquet(calib / "validation.parquet").set_index("flight")
    hover, gate = hover_input(d), d.certificate.gate
    false = []
    for name, lg in _logs(calib, "validation"):
        du = np.asarray(lg.u) - np.asarray(lg.uff) - hover
        dev = np.asarray(lg.y) - np.asarray(lg.ref)
        assert not innovation_flags(sound, dev, du, gate).any()
        bits = innovation_flags(spec, dev, du, gate)
        s = flight_statistic(sound, lg, hover, gate)
        assert bool(bits.any()) == (s > rec.quantile), (name, s, rec.quantile)
        if bits.any() and valid.loc[name, "assumptions_hold"]:
            false.append(name)  # a trip on a flight whose premise held
    lo, _ = clopper_pearson(len(false), 20)
    assert lo <= RATE and len(false) <= 4, false


def test_calibrate_records_the_calibrated_mode_verify_recomputes_it_and_an_edit_is_refused(
    calib, tmp_path
):
    """calibrate's own step (with_monitor) with monitor.mode calibrated writes the record
    the exported code and every reader fly; verify recomputes the statistics from the logs and
    reports an edited one; an edited quantile is refused on load, in one line."""
    from qsls.pipeline.calibrate.core import with_monitor
    from qsls.pipeline.calibrate.options import CalibrateOptions
    from qsls.pipeline.calibrate.verify import verify
    from qsls.pipeline.export.statement import statement

    out = tmp_path / "calibrate"
    shutil.copytree(calib, out)
    folder = _folder(out)
    before = load_controller_dir(folder).certificate.calibration.monitor
    opts = CalibrateOptions(monitor={"mode": "calibrated", "false_trip_rate": 0.2})
    logs = [lg for _, lg in _logs(out, "calibration")]
    with_monitor(load_controller_dir(folder), logs, opts.monitor).save(folder)
    d = load_controller_dir(folder)
    rec = d.certificate.calibration.monitor
    assert rec.mode == "calibrated" and rec.statistics == before.statistics
    assert rec.rank == 17 and rec.quantile == sorted(rec.statistics)[16] < before.quantile
    spec = innovation_of(d)
    assert spec.mode == "calibrated" and spec.scale == pytest.approx(rec.quantile, rel=2e-9)
    text = "\n".join(statement(d, monitor_of(d), ""))
    assert "calibrated: thresholds" in text and "at most 0.2" in text
    res = verify(out)
    assert res.verified, res.lines()
    raw = yaml.safe_load((folder / CERTIFICATE_FILE).read_text())
    raw["calibration"]["monitor"]["statistics"][0] *= 0.5  # not the quantile's flight
    assert raw["calibration"]["monitor"]["statistics"][0] * 2 != rec.quantile
    (folder / CERTIFICATE_FILE).write_text(yaml.safe_dump(raw, sort_keys=False))
    res = verify(out)
    assert [f.field for f in res.differences] == ["calibration.monitor.statistics[0]"]
    raw["calibration"]["monitor"]["quantile"] *= 0.9
    (folder / CERTIFICATE_FILE).write_text(yaml.safe_dump(raw, sort_keys=False))
    with pytest.raises(InputError, match="monitor quantile") as exc:
        load_controller_dir(folder)
    assert "\n" not in str(exc.value)
