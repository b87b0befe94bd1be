"""``qsls fit`` on VIO-emulator circle flights, real EuRoC flights, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.core.artifacts import StageWriter
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.references import Reference, ReferenceOptions
from qsls.pipeline.errormodel.fit import FIGURES, TRAINING_FILE, FitOptions, fit
from qsls.pipeline.errormodel.model import load_error_model
from qsls.pipeline.ingest.flight import E_COLS, X_COLS, make_flight_frame
from qsls.pipeline.premise.choose import lookup_eps_e, lookup_s
from qsls.pipeline.sim.vio import VioEmulator, VioParams

PNG = b"\x89PNG\r\n\x1a\n"


def write_flight(folder: Path, t: np.ndarray, x: np.ndarray, y: np.ndarray) -> Path:
    """A flight folder as 'qsls ingest' writes it (stage ingest, flight.parquet)."""
    with StageWriter(folder, "ingest") as w:
        w.write_parquet(
            "flight.parquet", make_flight_frame(np.round(t * 1e9).astype(np.int64), x, y)
        )
    return folder


def circle_states(seed: int, laps: float = 3.0, dt: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's default circle (radius 1 m, height 1 m, period 5 s, centred at the
    origin) plus smooth tracking deviations (consistent position and velocity), at ``dt``."""
    t = np.arange(0.0, laps * 5.0, dt)
    w = 2 * np.pi / 5.0
    z = np.zeros_like(t)
    x = np.c_[np.cos(w * t), np.sin(w * t), 1 + z, -w * np.sin(w * t), w * np.cos(w * t), z]
    rng = np.random.default_rng(seed)
    for k in range(3):
        for _ in range(3):
            a, w, ph = rng.uniform(0, 0.04), rng.uniform(0.2, 2.0), rng.uniform(0, 2 * np.pi)
            x[:, k] += a * np.sin(w * t + ph)
            x[:, 3 + k] += a * w * np.cos(w * t + ph)
    return t, x


MOTION_OFF = {"blur": False, "motion_drift": False, "feature_loss": False}


def vio_flights(root: Path, n: int = 3, **switches) -> tuple[list[Path], float]:
    """``n`` circle flights with the VIO emulator's errors; returns (folders, L)."""
    folders, lip = [], 0.0
    for seed in range(n):
        t, x = circle_states(seed)
        # the position-only emulator (its motion parts need body rates these states lack)
        vio = VioEmulator(VioParams(**{**MOTION_OFF, **switches}), seed)
        e = vio.errors(x)
        lip = vio.lipschitz
        folders.append(write_flight(root / f"flight{seed}", t, x, x + e))
    return folders, lip


# --------------------------------------------------------------------------- the VIO emulator
def test_bias_only_slope_is_bounded_by_L_and_reaches_half_of_it(tmp_path):
    flights, L = vio_flights(tmp_path, bias=True, noise=False, drift=False, outliers=False)
    res = fit(flights, FitOptions(radius=0.5, figures=False), tmp_path / "fit")
    s = res.model.s_slope
    assert L > 0.1
    # the theory: |b(x) - b(x')| <= L |x - x'| for every pair; tolerance: float rounding
    assert s.max <= L * (1 + 1e-9)
    assert s.max >= 0.5 * L
    assert res.model.n_pairs > 5000
    for w in res.model.worst_pairs:
        assert w.slope <= L * (1 + 1e-9)


def test_noise_and_outliers_blow_up_the_max_not_the_robust_percentile(tmp_path):
    # outliers a little more often than the default (2 % of samples), so 3 short flights
    # surely hold some
    flights, L = vio_flights(tmp_path, drift=False, outlier_prob=0.02)
    auto = fit(flights, FitOptions(radius=0.5, figures=False), tmp_path / "auto").model
    raw = fit(
        flights, FitOptions(radius=0.5, min_separation=0.0, figures=False), tmp_path / "raw"
    ).model
    # the paper's finding: a few bad measurements set the max (here > 20 L, > 50 L raw)
    assert auto.s_slope.max > 20 * L
    assert raw.s_slope.max > 50 * L
    # the robust value stays near the truth
    assert 0.25 * L <= auto.s_slope.percentiles["p50"] <= 2 * L
    # the minimum separation is the measured noise floor: velocity noise 0.015 m/s x texture
    assert 0.015 < auto.noise_floor["vx"] < 0.08
    assert auto.min_separation == pytest.approx(3 * max(auto.noise_floor.values()))
    assert auto.n_pairs_below_min_separation > 0 and raw.n_pairs_below_min_separation == 0
    # the pair that sets the max holds an injected velocity outlier (>= 0.3 m/s): the same
    # seed without outliers gives the same errors except at the outliers
    top = auto.worst_pairs[0]
    spike = 0.0
    for flight, t_k in ((top.flight, top.t_i), (top.flight_j, top.t_j)):
        seed = int(flight.removeprefix("flight"))
        t, x = circle_states(seed)
        k = int(np.argmin(np.abs(t - t_k)))
        on = VioEmulator(VioParams(drift=False, outlier_prob=0.02), seed).errors(x)[k]
        off = VioEmulator(VioParams(drift=False, outliers=False), seed).errors(x)[k]
        spike = max(spike, np.abs(on - off).max())
    assert spike >= 0.3
    # excluding outliers by robust z-score removes them and their slopes
    clean = fit(
        flights,
        FitOptions(radius=0.5, exclude_outliers=True, figures=False),
        tmp_path / "clean",
    ).model
    assert clean.exclusions["outliers"] > 0 and clean.n_excluded == clean.exclusions["outliers"]
    assert clean.s_slope.max < auto.s_slope.max
    assert clean.eps_e < 0.3 < auto.eps_e


# --------------------------------------------------------------------------- outputs
def test_outputs_figures_reference_and_determinism(tmp_path):
    flights, _ = vio_flights(tmp_path, n=2, drift=False)
    opts = FitOptions(
        radius=0.4,
        percentiles=[50, 99.5],
        reference="circle:radius=1.2,height=1,period=5,ramp_s=0",
        bootstrap=12,
        seed=7,
    )
    out = tmp_path / "fit"
    res = fit(flights, opts, out)
    model = load_error_model(out)
    assert model == res.model
    assert set(model.s_slope.percentiles) == {"p50", "p99.5"}
    # the premise looks the names up (premise/choose.py)
    assert lookup_s(model, "local_p99.5") == model.s_slope.local_max_percentiles["p99.5"]
    assert lookup_eps_e(model, "max") == model.eps_e == model.R0
    assert len(model.worst_pairs) == 20
    assert [w.slope for w in model.worst_pairs] == sorted(
        (w.slope for w in model.worst_pairs), reverse=True
    )
    # training states: the samples the model was fitted on
    df = pd.read_parquet(out / TRAINING_FILE)
    assert list(df.columns[:2]) == ["flight", "t"]
    assert set(X_COLS) | set(E_COLS) <= set(df.columns)
    assert len(df) == model.n_samples
    assert np.abs(df.loc[:, list(E_COLS)].to_numpy()).max() == model.eps_e
    # delta: a circle 0.2 m wider than the one flown is 0.2 m off in position (+ tracking)
    ref = Reference(ReferenceOptions(radius=1.2, period=5.0, ramp_s=0))
    o = ref.options
    rx = ref.states(o.start_s + np.arange(0, o.natural_duration() - o.start_s + 0.005, 0.01))
    tx = df.loc[:, list(X_COLS)].to_numpy()
    want = max(np.abs(tx - r).max(axis=1).min() for r in rx)
    assert model.delta == pytest.approx(want, rel=1e-12)
    assert 0.1 < model.delta < 0.5
    # bootstrap intervals bracket something sensible
    b = model.bootstrap
    assert b["replicates"] == 12 and b["seed"] == 7
    lo, hi = b["s_slope"]["p50"]
    assert lo <= hi and lo <= 1.5 * model.s_slope.percentiles["p50"]
    assert b["s_slope"]["max"][1] <= model.s_slope.max
    # figures render; manifest
    for name in FIGURES:
        assert (out / name).read_bytes()[:8] == PNG
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["stage"] == "fit" and manifest["results"]["n_pairs"] == model.n_pairs
    # same inputs, options and seed: byte-identical files
    again = tmp_path / "again"
    fit(flights, opts, again)
    for name in ("error_model.yaml", TRAINING_FILE, *FIGURES):
        assert (out / name).read_bytes() == (again / name).read_bytes(), name
    # a flight folder as the reference: delta to itself is 0
    own = fit(
        flights,
        FitOptions(radius=0.4, reference=str(flights[0]), figures=False),
        tmp_path / "own",
    )
    assert own.model.delta == 0.0


# --------------------------------------------------------------------------- the CLI
def test_cli_fit_and_bad_input(tmp_path):
    flights, _ = vio_flights(tmp_path, n=1, drift=False)
    runner = CliRunner()
    out = tmp_path / "cli"
    r = runner.invoke(
        app,
        [
            "fit",
            str(flights[0]),
            "--out",
            str(out),
            "--radius",
            "0.4",
            "--percentiles",
            "50,95",
            "--min-separation",
            "0.05",
            "--no-figures",
        ],
    )
    assert r.exit_code == 0, r.output
    model = load_error_model(out / "error_model.yaml")
    assert model.min_separation == 0.05 and model.min_separation_rule == "given"
    assert "S max" in r.output
    r = runner.invoke(app, ["fit", str(flights[0]), "--out", str(out)])
    assert r.exit_code == 2 and "already exists" in r.output

    other = tmp_path / "other"
    with StageWriter(other, "simulate") as w:
        w.write_text("truth.json", "{}")
    cases = {
        "no flights": ([], "no flights given"),
        "other tool": ([str(other)], "expected a 'ingest' folder"),
        "radius 0": ([str(flights[0]), "--radius", "0"], "radius"),
        "radius < 0": ([str(flights[0]), "--radius", "-1"], "radius"),
        "all excluded": (
            [str(flights[0]), "--skip-start", "1000"],
            "samples were excluded (skip_start",
        ),
        "bad reference": ([str(flights[0]), "--reference", "square:a=1"], "neither a flight"),
        "bad r0": ([str(flights[0]), "--r0", "p42"], "r0 'p42'"),
        "scale length": ([str(flights[0]), "--state-scale", "1,2"], "give 6 weights"),
        "min sep >= r": ([str(flights[0]), "--min-separation", "1"], "smaller than the radius"),
    }
    for name, (args, msg) in cases.items():
        bad = tmp_path / name.replace(" ", "_")
        r = runner.invoke(app, ["fit", *args, "--out", str(bad)])
        assert r.exit_code == 2, (name, r.output)
        lines = r.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), (name, r.output)
        assert msg in lines[0], (name, lines[0])
        assert not bad.exists(), name
        assert not list(tmp_path.glob(f".{bad.name}*")), name


def test_no_pairs_within_radius_is_a_clear_error(tmp_path):
    t = np.arange(5) * 0.1
    x = np.zeros((5, 6))
    x[:, 0] = np.arange(5) * 10.0
    f = write_flight(tmp_path / "sparse", t, x, x + 0.01)
    with pytest.raises(InputError, match="no pair of samples within radius"):
        fit([f], FitOptions(radius=0.5, figures=False), tmp_path / "out")
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- real flights
def test_real_euroc_flights_fit_and_render(real_data, tmp_path):
    from qsls.pipeline.ingest.stage import IngestOptions, ingest

    flights = []
    for name in ("euroc_v102_rpg", "euroc_mh04_rpg"):
        folder = real_data / name
        out = tmp_path / name
        ingest(
            [],
            IngestOptions(vio=folder / "estimate_tum.txt", truth=folder / "groundtruth_tum.txt"),
            out,
        )
        flights.append(out)
    res = fit(flights, FitOptions(radius=0.5, bootstrap=5), tmp_path / "fit")
    m = res.model
    assert m.n_samples > 1200 and m.n_pairs > 1000
    assert 0.01 < m.eps_e_percentiles["p50"] < m.eps_e < 5.0
    assert np.isfinite(m.s_slope.max) and m.s_slope.max >= m.s_slope.percentiles["p99"]
    assert all(np.isfinite(v) for v in m.s_slope.local_max_percentiles.values())
    assert m.flights == ["euroc_v102_rpg", "euroc_mh04_rpg"]
    durations = {f.name: pd.read_parquet(f / "flight.parquet")["t"].max() for f in flights}
    for w in m.worst_pairs:
        assert 0 <= w.t_i <= durations[w.flight] and 0 <= w.t_j <= durations[w.flight_j]
    for name in FIGURES:
        data = (tmp_path / "fit" / name).read_bytes()
        assert data[:8] == PNG and len(data) > 20_000


def test_exclusions_are_counted_by_reason(tmp_path):
    t, x = circle_states(4, laps=2)
    e = VioEmulator(VioParams(drift=False, outliers=False), 4).errors(x)
    y = x + e
    y[[20, 21, 50]] = np.nan  # a VIO dropout
    f = write_flight(tmp_path / "f", t, x, y)
    m = fit([f], FitOptions(radius=0.5, skip_start=1.0, figures=False), tmp_path / "out").model
    assert m.exclusions == {"nonfinite": 3, "skip_start": 10}
    assert m.n_excluded == 13 and m.n_samples == len(t) - 13
    df = pd.read_parquet(tmp_path / "out" / TRAINING_FILE)
    assert df["t"].min() >= 1.0 and np.isfinite(df.loc[:, list(E_COLS)].to_numpy()).all()


def test_fit_model_on_arrays_in_memory_matches_the_stage(tmp_path):
    """The pure core: :func:`fit_model` on samples built in memory (no file read or written)
    gives ``eps_e = max ||e||`` and the exact largest pair slope (against the all-pairs
    count), and the same error model ``qsls fit`` writes from the same samples on disk."""
    from qsls.pipeline.errormodel.fit import FitData, fit_model, load_fit_data
    from tests.reference_impl import brute_force_slopes

    rng = np.random.default_rng(3)
    ts, xs, es = [], [], []
    for seed in range(2):
        t, x = circle_states(seed, laps=1.0)
        ts.append(t)
        xs.append(x)
        es.append(0.02 * np.sin(x) + rng.normal(0, 0.002, x.shape))
    n = [len(t) for t in ts]
    data = FitData(
        names=["a", "b"], flight_idx=np.repeat([0, 1], n), t=np.concatenate(ts),
        x=np.concatenate(xs), e=np.concatenate(es), keep=np.ones(sum(n), bool),
        exclusions={}, dt=0.1,
    )  # fmt: skip
    opts = FitOptions(radius=0.3, min_separation=0.01, bootstrap=0, figures=False)
    before = set(tmp_path.iterdir())
    fitted = fit_model(data, opts)
    assert set(tmp_path.iterdir()) == before
    m = fitted.model
    assert m.eps_e == float(np.abs(data.e).max())
    _, s_max, count = brute_force_slopes(data.x, data.e, 0.3, min_separation=0.01)
    assert m.s_slope.max == pytest.approx(s_max, rel=1e-12) and m.n_pairs == count
    # the stage on the same samples written as two ingested flights
    folders = []
    for k, name in enumerate(("a", "b")):
        sel = data.flight_idx == k
        folders.append(
            write_flight(tmp_path / name, data.t[sel], data.x[sel], data.x[sel] + data.e[sel])
        )
    loaded = load_fit_data(folders, opts)
    np.testing.assert_allclose(loaded.e, data.e, atol=1e-12)
    res = fit(folders, opts, tmp_path / "fit")
    assert res.model.eps_e == pytest.approx(m.eps_e, abs=1e-12)
    assert res.model.s_slope.max == pytest.approx(m.s_slope.max, rel=1e-9)
    assert res.model.n_pairs == m.n_pairs


def test_environments_keep_distances_and_pairs_within_one_room(tmp_path):
    """Two flights in two rooms share no state space: with ``environments`` no pair crosses
    them (the pair count is the sum of each flight's own, against the all-pairs count per
    flight), leave-one-flight-out has nothing to leave out (S NaN, tested range 0), and a
    third flight in the first room is compared with that room's flight only."""
    from qsls.pipeline.errormodel.fit import FitData, fit_model, load_fit_data
    from qsls.pipeline.premise.measure import Spec, TrainingStates
    from tests.reference_impl import brute_force_slopes

    rng = np.random.default_rng(5)
    parts = []
    for seed in range(3):
        t, x = circle_states(seed, laps=1.0)
        parts.append((t, x, 0.02 * np.sin(x) + rng.normal(0, 0.002, x.shape)))
    n = [len(p[0]) for p in parts]
    data = FitData(
        names=["a", "b", "c"], flight_idx=np.repeat([0, 1, 2], n),
        t=np.concatenate([p[0] for p in parts]), x=np.concatenate([p[1] for p in parts]),
        e=np.concatenate([p[2] for p in parts]), keep=np.ones(sum(n), bool), exclusions={}, dt=0.1,
    )  # fmt: skip
    base = {"radius": 0.3, "min_separation": 0.01, "bootstrap": 0, "figures": False}
    together = fit_model(data, FitOptions(**base)).model
    apart_ = fit_model(data, FitOptions(**base, environments=["room", "hall", "room"])).model
    own = [brute_force_slopes(p[1], p[2], 0.3, min_separation=0.01)[2] for p in parts]
    pair_ac = brute_force_slopes(
        np.concatenate([parts[0][1], parts[2][1]]), np.concatenate([parts[0][2], parts[2][2]]),
        0.3, min_separation=0.01,
    )[2]  # fmt: skip
    assert apart_.n_pairs == pair_ac + own[1] < together.n_pairs
    # the premise's leave-one-flight-out distances: b alone in its room (inf), a and c paired
    env = np.repeat([0, 1, 0], n)
    ts = TrainingStates(data.x, data.e, data.flight_idx, environment=env)
    meas = ts.measured(Spec(radius=1.0))
    assert np.isinf(meas.dist_other[data.flight_idx == 1]).all()
    a = data.flight_idx == 0
    from scipy.spatial import cKDTree

    want = cKDTree(parts[2][1]).query(parts[0][1], p=np.inf)[0]
    np.testing.assert_allclose(meas.dist_other[a], want, rtol=1e-12)
    alone = TrainingStates(data.x[data.flight_idx < 2], data.e[data.flight_idx < 2],
                           data.flight_idx[data.flight_idx < 2], environment=env[: n[0] + n[1]])  # fmt: skip
    fit_alone = alone.measured(Spec(radius=1.0)).slope
    assert np.isnan(fit_alone.S) and fit_alone.tested_range == 0.0
    # one name per flight, or a clear error
    folders = [
        write_flight(tmp_path / k, p[0], p[1], p[1] + p[2])
        for k, p in zip("ab", parts, strict=False)
    ]
    with pytest.raises(InputError, match="one environment per flight"):
        load_fit_data(folders, FitOptions(**base, environments=["room"]))
