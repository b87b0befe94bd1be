"""A run config resolved into each stage's options in one pass (run/sections.py): the flights'
overlays, the run's ``simulate:`` under ``calibrate.sim`` and ``fly.sim``, the recorded paths
and the calibration's seeds checked against the resolved flights'; the graph then built from
those options alone (docs/run.md#sections). Nothing runs: each test plans a config."""

from __future__ import annotations

import pytest
import yaml

from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.evaluate.options import EvaluateOptions
from qsls.pipeline.run.runner import load_run_config
from qsls.pipeline.run.sections import resolve_sections
from qsls.pipeline.run.stages import build_graph

SIMULATE = {"duration": 3, "reference": {"radius": 1.5, "period": 6.0}, "vio": {"noise": False}}
FLIGHTS = [
    {"name": "a", "role": "train", "simulate": {"reference": {"period": 4.0}}},
    {"name": "b", "role": "train", "simulate": {"seed": 40, "vio": {"perception": "degraded"}}},
    {"name": "c", "role": "heldout", "simulate": {}},
]


def _sections(tmp_path, **changes):
    raw = {"name": "r", "seed": 7, "simulate": SIMULATE, "flights": FLIGHTS, **changes}
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    cfg = load_run_config(path)
    return cfg, resolve_sections(cfg, tmp_path)


def test_each_flight_lays_its_own_simulate_over_the_runs_and_takes_the_runs_seed_plus_its_index(
    tmp_path,
):
    _, sec = _sections(tmp_path)
    a, b, c = sec.flights
    assert b.sim.vio.perception == "degraded" and b.sim.reference.period == 6.0
    # the run's seed plus the flight's index, unless the flight gives one
    assert [f.sim.seed for f in sec.flights if f.sim] == [7, 40, 9]
    # nested mappings merge: the flight's period over the run's radius
    assert (a.sim.reference.radius, a.sim.reference.period) == (1.5, 4.0)
    assert (c.sim.reference.radius, c.sim.reference.period) == (1.5, 6.0)
    assert [f.perception for f in sec.flights] == ["regular", "degraded", "regular"]
    assert [f.role for f in sec.flights] == ["train", "train", "heldout"]
    assert all(f.sim.duration == 3 and f.sources == () for f in sec.flights if f.sim)


def test_calibrate_and_fly_fly_the_runs_simulate_conditions_under_their_own_keys(tmp_path):
    calibrate = {"seed": 500, "flights": 5, "validation": 5, "validation_seed": 600,
                 "sim": {"duration": 9}}  # fmt: skip
    fly = {"seeds": [1], "sim": {"reference": {"radius": 0.5}}}
    _, sec = _sections(tmp_path, calibrate=calibrate, fly=fly)
    assert sec.calibrate is not None and sec.fly is not None
    assert (sec.calibrate.sim.duration, sec.calibrate.sim.reference.radius) == (9, 1.5)
    assert (sec.fly.sim.duration, sec.fly.sim.reference.radius) == (3, 0.5)
    assert sec.fly.sim.reference.period == 6.0
    # the design seeds were checked, not recorded: the stage's outputs do not depend on them
    assert sec.calibrate.design_seeds == []


def test_a_calibration_seed_a_flight_flew_is_refused_with_the_flights_resolved_seed(tmp_path):
    # flight c takes the run's seed 7 + 2 = 9: a calibration starting at 8 reaches it
    with pytest.raises(ConfigError) as exc:
        _sections(tmp_path, calibrate={"seed": 8, "flights": 3, "validation_seed": 600})
    assert str(exc.value).startswith(f"{tmp_path}: calibrate: calibration seeds [9] are design")


def test_a_recorded_flights_paths_are_taken_from_the_configs_folder_and_must_exist(tmp_path):
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "vio.csv").write_text("")
    (tmp_path / "logs" / "truth.csv").write_text("")
    rec = {"name": "rec", "role": "train", "vio": "logs/vio.csv", "truth": "logs/truth.csv"}
    _, sec = _sections(tmp_path, flights=[rec])
    (f,) = sec.flights
    assert f.sim is None and f.perception == "" and f.estimator == ""
    assert f.external == (tmp_path / "logs" / "vio.csv", tmp_path / "logs" / "truth.csv")
    (tmp_path / "logs" / "truth.csv").unlink()
    with pytest.raises(ConfigError, match=r"flight 'rec': .*logs/truth.csv does not exist$"):
        _sections(tmp_path, flights=[rec])


def test_the_graph_is_built_from_the_sections_and_the_asked_for_stages(tmp_path):
    _, sec = _sections(tmp_path, synth={"T": 6}, evaluate={"figures": False})
    ids = build_graph(sec, None, tmp_path / "out").ids
    assert ids == ["simulate/a", "ingest/a", "simulate/b", "ingest/b", "simulate/c",
                   "ingest/c", "fit", "synth", "evaluate"]  # fmt: skip
    assert build_graph(sec, ["simulate", "ingest"], tmp_path / "out").ids == ids[:6]
    deps = {s.id: s.deps for s in build_graph(sec, None, tmp_path / "out").stages}
    # the simulated training flights logged their inputs: the fit reads them; the held-out
    # flight goes to the evaluation only
    assert deps["fit"] == ("ingest/a", "ingest/b", "simulate/a", "simulate/b")
    assert deps["evaluate"] == ("fit", "synth", "ingest/c")
    with pytest.raises(ConfigError, match=r": stages: fly is listed but the config has no fly"):
        build_graph(sec, ["simulate", "ingest", "fit", "synth", "fly"], tmp_path / "out")


def test_every_section_is_checked_whichever_stages_the_config_lists(tmp_path):
    # flight c's seed 9 lies in the calibration's seeds even when only simulate and ingest run
    with pytest.raises(ConfigError, match=r": calibrate: calibration seeds \[9\] are design"):
        _sections(tmp_path, stages=["simulate", "ingest"],
                  calibrate={"seed": 9, "flights": 1, "validation_seed": 600})  # fmt: skip


def test_a_heldout_flight_without_an_evaluate_section_is_checked_with_the_default_options(
    tmp_path,
):
    _, sec = _sections(tmp_path, synth={"T": 6})
    assert sec.evaluate is None
    stage = next(s for s in build_graph(sec, None, tmp_path / "out").stages if s.id == "evaluate")
    assert stage.deps == ("fit", "synth", "ingest/c")
    assert stage.options == EvaluateOptions()


def test_a_missing_recorded_file_is_said_before_a_bad_ingest_option(tmp_path):
    rec = {"name": "rec", "role": "train", "vio": "nowhere/vio.csv", "truth": "nowhere/t.csv",
           "ingest": {"dtt": 0.1}}  # fmt: skip
    with pytest.raises(ConfigError, match=r"flight 'rec': .*nowhere/vio.csv does not exist"):
        _sections(tmp_path, flights=[rec])
