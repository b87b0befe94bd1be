"""Issue 50's last input-handling items: the warnings a user needs (an evaluated flight that
is a training flight's twin; ingest streams that look swapped; an implausible ingest error),
the calibration's refusal naming the premise quantity it found broken, the certificate
reader's alias refusal naming its file, and refusals that lead with what to do."""

from __future__ import annotations

import pytest

from qsls.pipeline.core.errors import InputError


def _bomb(levels: int = 9) -> list[str]:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{k}: &a{k} [{', '.join([f'*a{k - 1}'] * 9)}]" for k in range(1, levels + 1)]
    return lines


def test_a_certificate_alias_bomb_refusal_names_the_file(tmp_path):
    from qsls.pipeline.control.artifacts import Certificate

    cert = tmp_path / "ctrl" / "certificate.yaml"
    cert.parent.mkdir()
    cert.write_text("controller: l1\n" + "".join(f"{ln}\n" for ln in _bomb()) + "b: *a9\n")
    with pytest.raises(InputError, match="expands to more than") as exc:
        Certificate.load(cert.parent)
    assert str(exc.value).startswith(f"{cert}:")


# --------------------------------------------------------------------------- no inflation covers
def _premise(**kw):
    from qsls.pipeline.premise.numbers import PremiseNumbers

    base = dict(eps=0.05, S=0.2, radius=1.0, eps_w=0.06, delta=0.3, eps_o=0.5, m=2)
    return PremiseNumbers(**{**base, **kw})


def _row(**kw):
    row = dict(dense=0.4, disturbance=0.7, reference=0.5, outliers=0.5, score=0.7,
               reached=0.2, w_max=0.04, window_max=1.0, ref_max=0.15, outlier_max=0.1)  # fmt: skip
    return {**row, **kw}


def test_the_calibration_refusal_names_the_reference_its_value_and_the_fix():
    """The issue's case: fitted without a reference, Delta is 0 and every calibration flight's
    reference part is inf; the refusal said only 'a premise quantity no inflation covers'."""
    import math

    from qsls.pipeline.calibrate.core import Rule, Scores, decide

    nominal = _premise(delta=0.0)
    rows = [
        _row(role="calibration", reference=math.inf, score=math.inf, ref_max=0.2 + 0.01 * k)
        for k in range(20)
    ]
    d = decide(Scores.of(rows), nominal, None, Rule(0.1))  # type: ignore[arg-type]
    status, reason, lam = d.status, d.reason, d.lambda_hat
    assert status == "relaxed" and math.isinf(lam)
    assert "reference (20 flights): dist(x_ref) reaches 0.39 over Delta 0" in reason
    assert "qsls fit --reference" in reason and "qsls synth --delta" in reason
    assert "disturbance" not in reason and len(reason) < 300


def test_the_refusal_names_each_infinite_quantity_once_with_its_largest_value():
    import math

    from qsls.pipeline.calibrate.core import broken_premise

    rows = [
        _row(outliers=math.inf, score=math.inf, outlier_max=0.9),
        _row(outliers=math.inf, disturbance=math.inf, score=math.inf, outlier_max=1.3,
             w_max=0.02),
    ]  # fmt: skip
    text = broken_premise(rows, _premise(eps_w=0.0))
    assert "outliers (2 flights): an outlier of 1.3 exceeds eps_o 0.5" in text
    assert "disturbance (1 flight): ||H^-1 w|| reaches 0.02 over eps_w 0" in text
    assert text.index("disturbance") < text.index("outliers")  # the score table's order
    m0 = broken_premise([_row(outliers=math.inf, window_max=3.0)], _premise(m=0))
    assert "outliers (1 flight): 3 outliers in a window of T ticks over m 0" in m0


# --------------------------------------------------------------------------- ingest warnings
def _tum(path, rate_hz, noise, seed, radius=1.0, direction=1.0, seconds=40.0):
    """A TUM file of a 1 m circle (5 s period) at ``rate_hz`` with white position noise."""
    import numpy as np

    from qsls.pipeline.ingest.sources.text.writer import tum_text

    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    w = direction * 2 * np.pi / 5.0
    p = np.column_stack([radius * np.cos(w * t), radius * np.sin(w * t), 1.0 + 0.2 * np.sin(t)])
    p += noise * rng.standard_normal(p.shape)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    path.write_text(tum_text((t * 1e9 + 1e18).astype(np.int64), p, q))
    return path


@pytest.fixture(scope="module")
def tum_streams(tmp_path_factory):
    d = tmp_path_factory.mktemp("tum")
    return {
        "truth": _tum(d / "mocap.txt", 200.0, 0.0005, 1),
        "vio": _tum(d / "vio.txt", 20.0, 0.02, 2),
        "other": _tum(d / "other.txt", 20.0, 0.02, 3, radius=3.0, direction=-1.0),
    }


def _ingest(tmp_path, vio, truth):
    from qsls.pipeline.ingest.options import IngestOptions
    from qsls.pipeline.ingest.stage import ingest

    out = tmp_path / f"{vio.stem}_{truth.stem}"
    return ingest([], IngestOptions(vio=vio, truth=truth, dt=0.05, time_offset=0.0), out)


def test_ingest_of_the_right_streams_warns_nothing(tmp_path, tum_streams):
    r = _ingest(tmp_path, tum_streams["vio"], tum_streams["truth"])
    assert r.rms_position_m < 0.05 and r.warnings == ()


def test_swapped_streams_are_named_with_the_flags_to_swap(tmp_path, tum_streams):
    import json

    r = _ingest(tmp_path, tum_streams["truth"], tum_streams["vio"])
    (w,) = r.warnings
    assert w.startswith("the streams look swapped: swap --vio-topic and --truth-topic")
    assert "'mocap.txt' is the ground truth and 'vio.txt' the estimate" in w
    assert "it records at 200 Hz, the truth at 20 Hz" in w
    ratio = float(w.split("second differences are ")[1].split(" x")[0])
    assert ratio < 0.8  # the "truth" (the estimate: 2 cm noise) is the rougher
    manifest = json.loads((r.out / "manifest.json").read_text())
    assert manifest["results"]["warnings"] == [w]


def test_a_smoother_vio_at_the_truths_rate_looks_swapped_too():
    import numpy as np
    import pyarrow as pa

    from qsls.pipeline.ingest.plausible import swapped

    rng = np.random.default_rng(0)
    t = np.arange(0, 20, 0.1)
    smooth = np.column_stack([np.cos(t), np.sin(t), np.ones_like(t)])
    rough = smooth + 0.02 * rng.standard_normal(smooth.shape)
    cols = {"t": t, **{f"x_p{a}": rough[:, i] for i, a in enumerate("xyz")},
            **{f"y_p{a}": smooth[:, i] for i, a in enumerate("xyz")}}  # fmt: skip
    res = {"dt": 0.1, "streams": {"vio": {"topic": "/a", "rate_hz": 100.0},
                                  "truth": {"topic": "/b", "rate_hz": 100.0}}}  # fmt: skip
    assert "'/a' is the ground truth" in swapped(pa.table(cols), res)
    flipped = {**cols, **{f"x_p{a}": smooth[:, i] for i, a in enumerate("xyz")},
               **{f"y_p{a}": rough[:, i] for i, a in enumerate("xyz")}}  # fmt: skip
    assert swapped(pa.table(flipped), res) is None
    # a faster VIO that is the rougher stream (an IMU-rate estimate against a 20 Hz tracker)
    fast = {**res, "streams": {"vio": {"topic": "/a", "rate_hz": 200.0},
                               "truth": {"topic": "/b", "rate_hz": 20.0}}}  # fmt: skip
    assert swapped(pa.table(flipped), fast) is None


def test_an_implausible_rms_error_warns_and_the_cli_prints_it(tmp_path, tum_streams):
    from typer.testing import CliRunner

    from qsls.cli.main import app

    out = tmp_path / "far"
    res = CliRunner().invoke(app, ["ingest", "--vio", str(tum_streams["other"]), "--truth",
                                   str(tum_streams["truth"]), "--out", str(out), "--dt", "0.05",
                                   "--time-offset", "0"])  # fmt: skip
    assert res.exit_code == 0, res.output
    line = next(ln for ln in res.stderr.splitlines() if "RMS position error" in ln)
    assert line.startswith("warning: check the topics, frames and clocks: ")
    rms = float(line.split("truth is ")[1].split(" m")[0])
    assert rms > 1.0 and "(0 gaps), above 1 m" in line


# --------------------------------------------------------------------------- twins
@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """Three TUM flights of circles of radius 1, 1.5 and 2 m ingested, and an error model
    fitted on the first two (a real fit)."""
    from qsls.pipeline.errormodel.fit import fit
    from qsls.pipeline.errormodel.options import FitOptions
    from qsls.pipeline.ingest.options import IngestOptions
    from qsls.pipeline.ingest.stage import ingest

    d = tmp_path_factory.mktemp("twins")
    folders = {}
    for k, radius in enumerate((1.0, 1.5, 2.0)):
        truth = _tum(d / f"truth{k}.txt", 200.0, 0.0005, 10 + k, radius=radius)
        vio = _tum(d / f"vio{k}.txt", 20.0, 0.02, 20 + k, radius=radius)
        opts = IngestOptions(vio=vio, truth=truth, dt=0.1, time_offset=0.0)
        folders[k] = ingest([], opts, d / f"f{k}").out
    # the first flight's truth with another estimate: one flight, two ingests
    vio = _tum(d / "vio0b.txt", 20.0, 0.03, 99)
    opts = IngestOptions(vio=vio, truth=d / "truth0.txt", dt=0.1, time_offset=0.0)
    folders["again"] = ingest([], opts, d / "f0_again").out
    fit([folders[0], folders[1]], FitOptions(), d / "fit")
    return d, folders


def test_a_held_out_twin_of_a_training_flight_is_named_with_it(fitted):
    import shutil

    from qsls.pipeline.evaluate.stage import load_flights
    from qsls.pipeline.evaluate.twins import twin_warnings

    d, f = fitted
    copy = d / "copy_of_f0"
    if not copy.exists():
        shutil.copytree(f[0], copy)
    held = [f[2], f[0], copy, f["again"]]
    ws = twin_warnings(held, load_flights(held), d / "fit")
    assert len(ws) == 3  # f2 is another flight
    assert ws[0].startswith("evaluate a flight the fit did not see: held-out flight 'f0'")
    assert f"is training flight 'f0' ({f[0]})'s twin (the same folder)" in ws[0]
    assert "'copy_of_f0'" in ws[1] and "(the same ground truth)" in ws[1]
    assert "'f0_again'" in ws[2] and "'f0'" in ws[2]
    # the training folders gone, the fit's training states still tell
    moved = d / "moved"
    if not moved.exists():
        moved.mkdir()
        shutil.copytree(f[0], moved / "f0")
        shutil.copytree(f[2], moved / "f2")
    gone = [moved / "f2", moved / "f0"]
    saved = {k: d / f"f{k}" for k in (0, 1)}
    for k, p in saved.items():
        p.rename(d / f"away{k}")
    try:
        ws = twin_warnings(gone, load_flights(gone), d / "fit")
    finally:
        for k, p in saved.items():
            (d / f"away{k}").rename(p)
    assert len(ws) == 1 and "held-out flight 'f0'" in ws[0] and "training flight 'f0''s" in ws[0]


# --------------------------------------------------------------------------- the fix first
def test_a_truth_that_jumps_everywhere_is_refused_with_the_fix_first(tmp_path, tum_streams):
    """One of the longest refusals (320 characters of text) named its fix last."""
    truth = _tum(tmp_path / "jumpy.txt", 200.0, 0.5, 7)  # 0.5 m of noise at 200 Hz
    with pytest.raises(InputError) as exc:
        _ingest(tmp_path, tum_streams["vio"], truth)
    msg = str(exc.value)
    assert msg.startswith("truth stream jumpy.txt: check --truth-topic and --vio-topic")
    assert "jumps no vehicle could fly" in msg and len(msg) < 300
