"""One YAML section, two readers: a ``qsls run`` config's ``sweep:``, ``evaluate:`` and ``fly:``
sections (with the keys that say where and how to run: ``jobs``, ``scheduler``,
``wait_workers``) and its ``simulate:`` and ``ingest:`` sections (the bases of every flight's
own) work unchanged for the stage command with ``--config``, and the other way round; a
misspelled key is the same one-line error from both."""

from __future__ import annotations

import json
import re

import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.control.sweep import SweepSection
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.run.runner import load_run_config, plan, run
from tests.test_runner_direct import BASE, _flights

SIMULATE = {"duration": 2, "vio": {"noise": False}, "log": {"format": "mcap"}}
INGEST = {"dt": 0.1, "align": "4dof", "time_offset": -0.137, "min_overlap": 1.0}
SWEEP = {
    "grid": {"S": [0.0, 0.01]},
    "T": 6,
    "eps_e": 0.05,
    "radius": 1.0,
    "s_max_curve": False,
    "jobs": 2,
}
EVALUATE = {"figures": False, "smooth_s": 0.5}
FLY = {"figures": False, "smooth_s": 0.5, "seeds": [3], "jobs": 1, "duration": 5}


def _write(folder, **changes):
    path = folder / "run.yaml"
    path.write_text(yaml.safe_dump({**BASE, **changes}, sort_keys=False))
    return path


def _cli(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def _manifest(folder):
    return json.loads((folder / "manifest.json").read_text())


@pytest.fixture
def work(tmp_path):
    (tmp_path / "cfg").mkdir()
    _flights(tmp_path / "cfg")
    return tmp_path


def test_the_sweep_section_of_a_run_config_works_for_qsls_sweep_and_qsls_run(work):
    cfg = _write(work / "cfg", sweep=SWEEP, evaluate=EVALUATE, stages=["ingest", "fit", "sweep"])
    # the stage command reads the run config's section, jobs included
    res = _cli("sweep", "--config", cfg, "--out", work / "alone")
    assert res.exit_code == 0, res.output
    alone = _manifest(work / "alone")
    assert alone["results"]["executor"] == "local, 2 processes"
    assert "jobs" not in alone["options"]  # where it ran is not part of the sweep's record
    # the run reads the same section the same way
    result = run(cfg, out=work / "run")
    assert [o.id for o in result.outcomes if o.status == "ran"][-1] == "sweep"
    in_run = _manifest(work / "run" / "sweep")
    assert in_run["results"]["executor"] == "local, 2 processes"
    assert in_run["options"] == alone["options"]
    a, b = (pd.read_parquet(f / "sweep.parquet") for f in (work / "alone", work / "run" / "sweep"))
    assert list(a["S"]) == list(b["S"]) == [0.0, 0.01]
    assert list(a["feasible"]) == list(b["feasible"])
    # the command line's executor replaces the file's
    res = _cli("sweep", "--config", cfg, "--out", work / "one", "--jobs", 1)
    assert res.exit_code == 0, res.output
    assert _manifest(work / "one")["results"]["executor"] == "local, 1 process"


def test_the_evaluate_and_fly_sections_are_read_the_same_by_both(work):
    cfg = _write(work / "cfg", evaluate=EVALUATE, fly=FLY)
    graph = plan(load_run_config(cfg), cfg, work / "out")
    by = {s.id: s.options for s in graph.stages}
    bound, fly = by["evaluate"], by["fly"]
    assert (bound.figures, bound.smooth_s) == (False, 0.5)
    # fly is a section of its own (issue 49): its keys only, the run's simulate: under its sim
    assert (fly.figures, fly.smooth_s, fly.seeds, fly.jobs, fly.duration) == (
        False, 0.5, [3], 1, 5.0
    )  # fmt: skip
    assert {s.id: s.kind for s in graph.stages}["fly"] == "fly"
    # the stage command on the same file: the bound check with the section's options
    ran = run(_write(work / "cfg", evaluate=EVALUATE, fly=FLY, stages=["ingest", "fit", "synth"]),
              out=work / "run")  # fmt: skip
    assert {o.id for o in ran.outcomes} >= {"fit", "synth", "ingest/c"}
    res = _cli(
        "evaluate", "--config", cfg, "--model", work / "run" / "fit",
        "--controller", work / "run" / "synth", "--flights", work / "run" / "ingest" / "c",
        "--out", work / "ev",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    options = _manifest(work / "ev")["options"]
    assert options == json.loads(json.dumps(bound.model_dump(mode="json")))
    assert not list((work / "ev").glob("*.png"))  # figures: false from the section


@pytest.mark.parametrize(
    "section, message",
    [
        ({**SWEEP, "jbos": 2}, "unknown option 'jbos'; did you mean 'jobs'?"),
        ({**SWEEP, "jobs": 2, "scheduler": "tcp://127.0.0.1:8786"}, "give jobs or scheduler"),
        ({**SWEEP, "jobs": None, "scheduler": "tcp://127.0.0.1"}, "missing port number"),
        ({**SWEEP, "wait_workers": 0}, "'wait_workers': Input should be greater than 0"),
    ],
)
def test_a_bad_sweep_section_is_the_same_error_for_both(work, section, message):
    cfg = _write(work / "cfg", sweep=section)
    with pytest.raises(ConfigError, match="sweep: .*" + message.replace("(", r"\(")):
        plan(load_run_config(cfg), cfg, work / "out")
    res = _cli("sweep", "--config", cfg, "--out", work / "o")
    assert res.exit_code == 2 and message in res.output and "Traceback" not in res.output
    assert not (work / "o").exists()


def test_sweep_section_splits_into_the_sweeps_options_and_where_it_runs():
    sec = SweepSection.model_validate({**SWEEP, "wait_workers": 5})
    assert (sec.jobs, sec.scheduler, sec.wait_workers) == (2, None, 5.0)
    opts = sec.options()
    assert type(opts).__name__ == "SweepOptions" and opts.T == 6 and opts.grid == SWEEP["grid"]
    assert not {"jobs", "scheduler", "wait_workers"} & set(opts.model_dump())


def test_the_simulate_and_ingest_sections_work_for_their_commands_and_under_each_flight(work):
    """A simulated flight of a run is its own ``simulate:`` laid over the section; the stage
    commands reading the same file (the flight's keys given on the command line) write the
    same options, the same bag and the same flight table."""
    flight = {"name": "s", "simulate": {"seed": 4, "vio": {"perception": "degraded"}}}
    cfg = _write(work / "cfg", simulate=SIMULATE, ingest=INGEST, flights=[flight],
                 stages=["simulate", "ingest"])  # fmt: skip
    ran = run(cfg, out=work / "run")
    assert {o.id for o in ran.outcomes if o.status == "ran"} == {"simulate/s", "ingest/s"}
    in_run = _manifest(work / "run" / "simulate" / "s")["options"]
    # the flight's keys and the section's, merged (vio: both)
    assert (in_run["seed"], in_run["duration"], in_run["log"]["format"]) == (4, 2.0, "mcap")
    assert (in_run["vio"]["perception"], in_run["vio"]["noise"]) == ("degraded", False)
    res = _cli("simulate", "--config", cfg, "--seed", 4, "--perception", "degraded",
               "--out", work / "alone")  # fmt: skip
    assert res.exit_code == 0, res.output
    assert _manifest(work / "alone")["options"] == in_run
    bag = (work / "alone" / "flight.mcap").read_bytes()
    assert bag == (work / "run" / "simulate" / "s" / "flight.mcap").read_bytes()
    res = _cli("ingest", work / "alone" / "flight.mcap", "--config", cfg, "--out", work / "ing")
    assert res.exit_code == 0, res.output
    options = _manifest(work / "ing")["options"]
    assert options == _manifest(work / "run" / "ingest" / "s")["options"]
    assert (options["min_overlap"], options["time_offset"]) == (1.0, -0.137)
    table = (work / "ing" / "flight.parquet").read_bytes()
    assert table == (work / "run" / "ingest" / "s" / "flight.parquet").read_bytes()
    # a flight's own keys are still checked when planned, the error naming the flight
    bad = {**flight, "simulate": {"vio": {"perceptoin": "degraded"}}}
    cfg = _write(work / "cfg", simulate=SIMULATE, flights=[bad])
    with pytest.raises(ConfigError, match=r"\(flight 's'\): unknown option 'vio.perceptoin'"):
        plan(load_run_config(cfg), cfg, work / "p")


@pytest.mark.parametrize(
    "key, section, message",
    [
        ("simulate", {**SIMULATE, "vio": {"noize": 0.1}},
         "unknown option 'vio.noize'; did you mean 'noise'?"),
        ("simulate", {**SIMULATE, "duratoin": 3}, "unknown option 'duratoin'; did you mean 'duration'?"),
        # a base must be valid alone, as for the stage command: the default outlier_max is 1
        ("simulate", {"vio": {"outlier_min": 2.0}},
         "'vio.outlier_max': outlier_max (1.0) must be >= outlier_min (2.0)"),
        ("ingest", {**INGEST, "algin": "se3"}, "unknown option 'algin'; did you mean 'align'?"),
        ("ingest", {**INGEST, "dt": -1}, "'dt': Input should be greater than 0"),
    ],
)  # fmt: skip
def test_a_bad_simulate_or_ingest_section_is_one_error_naming_it_from_both(
    work, key, section, message
):
    cfg = _write(work / "cfg", **{key: section})
    escaped = message.replace("(", r"\(").replace(")", r"\)").replace("?", r"\?")
    # when the config is read, before any flight is planned
    with pytest.raises(ConfigError, match=f"cfg: {key}: {escaped}"):
        load_run_config(cfg)
    res = _cli(key, "--config", cfg, "--out", work / "o")
    assert res.exit_code == 2 and message in res.output and "Traceback" not in res.output
    assert not (work / "o").exists()


def test_run_config_sections_are_the_stage_commands_option_models(work):
    """``RunConfig`` holds each stage section as the very model the stage command reads with
    ``--config`` (equal objects from one file), records them as written, names the section in
    an error, and reading it loads no solver, pandas or simulator."""
    import subprocess
    import sys

    from qsls.pipeline.control.options import SynthOptions
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.errormodel.options import FitOptions
    from qsls.pipeline.evaluate.section import EvaluateSection
    from qsls.pipeline.ingest.stage import IngestOptions
    from qsls.pipeline.sim.simulate import SimOptions

    synth = {"T": 6, "R": [10, 10, 1], "S": 0.05}
    cfg = _write(work / "cfg", sweep=SWEEP, evaluate=EVALUATE, synth=synth, fit={"radius": 0.8},
                 simulate=SIMULATE, ingest=INGEST)  # fmt: skip
    rc = load_run_config(cfg)
    for key, model in (("fit", FitOptions), ("synth", SynthOptions), ("sweep", SweepSection),
                       ("evaluate", EvaluateSection), ("simulate", SimOptions),
                       ("ingest", IngestOptions)):  # fmt: skip
        section = getattr(rc, key)
        assert type(section) is model and section == load_options(model, cfg, section=key)
    assert rc.synth is not None and rc.synth.R == [[10, 0, 0], [0, 10, 0], [0, 0, 1]]
    assert (rc.simulate.duration, rc.simulate.vio.noise, rc.ingest.min_overlap) == (2.0, False, 1.0)
    record = rc.record()
    assert record["synth"] == synth and record["fit"] == {"radius": 0.8}
    # as written, not the models' dumps (a default added to a model does not plan anew)
    assert (record["simulate"], record["ingest"]) == (SIMULATE, INGEST)
    assert load_run_config(_write(work / "cfg")).record()["simulate"] == {}
    code = (
        "import sys; from qsls.pipeline.run.runner import load_run_config; "
        f"load_run_config({str(cfg)!r}); "
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'cvxpy', 'scipy', 'pandas', "
        "'matplotlib', 'rotorpy', 'pyarrow', 'clarabel', 'dask', 'cv2', 'rosbags', 'mcap'}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
    with pytest.raises(ConfigError, match=r"cfg: synth: unknown option 'TT'; did you mean 'T'\?"):
        load_run_config(_write(work / "cfg", synth={"TT": 6}))


def test_a_run_config_made_in_python_lays_each_flight_over_its_sections(tmp_path):
    """Without a file, the sections as written are the keys set on the models: the flight's
    own options still lie over them, and the record holds only those keys."""
    from qsls.pipeline.ingest.options import IngestOptions
    from qsls.pipeline.run.runner import FlightSpec, RunConfig
    from qsls.pipeline.sim.options import SimOptions

    rc = RunConfig(
        name="py",
        simulate=SimOptions(duration=2, vio={"noise": False}),
        ingest=IngestOptions(dt=0.2),
        flights=[FlightSpec(name="s", simulate={"seed": 4, "vio": {"perception": "degraded"}})],
    )
    assert rc.written("simulate") == {"duration": 2.0, "vio": {"noise": False}}
    assert rc.record()["ingest"] == {"dt": 0.2} and rc.record()["sweep"] is None
    by = {s.id: s.options for s in plan(rc, tmp_path / "run.yaml", tmp_path / "out").stages}
    sim = by["simulate/s"]
    assert (sim.duration, sim.seed, sim.vio.noise, sim.vio.perception) == (
        2.0,
        4,
        False,
        "degraded",
    )
    assert sim.vio.outliers and by["ingest/s"]["options"].dt == 0.2


def test_a_bad_fly_section_is_refused_when_the_config_is_read(work):
    """``fly:`` is validated with the flying options when the config is read, not first when
    the run is planned; the same keys for ``qsls fly --config`` name the same problem."""
    cfg = _write(work / "cfg", fly={"figures": False, "seedz": [1]})
    with pytest.raises(
        ConfigError, match=r"cfg: fly: unknown option 'seedz'; did you mean 'seeds'\?"
    ):
        load_run_config(cfg)
    res = _cli("fly", "--config", cfg, "--model", work, "--controller", work, "--out", work / "f")
    assert res.exit_code == 2
    assert "unknown option 'seedz'; did you mean 'seeds'?" in res.output
    cfg = _write(work / "cfg", fly={"vio": ["camera", "camera"]})
    with pytest.raises(ConfigError, match="give each estimator once"):
        load_run_config(cfg)


def test_fly_under_evaluate_is_refused_with_a_pointer_to_its_own_section(work):
    """Issue 49: an old config's ``evaluate: {fly: ...}`` gets, for one release, one line saying
    where the options went, from the run, ``qsls fly`` and ``qsls evaluate`` alike."""
    cfg = _write(work / "cfg", evaluate={"figures": False, "fly": {"seeds": [1]}})
    moved = "evaluate: 'fly': flying is a stage of its own now: move this mapping out of evaluate:"
    with pytest.raises(ConfigError, match=re.escape(f"cfg: {moved}")):
        load_run_config(cfg)
    for command in ("fly", "evaluate"):
        res = _cli(command, "--config", cfg, "--model", work, "--controller", work,
                   "--out", work / command)  # fmt: skip
        assert res.exit_code == 2, res.output
        assert moved.partition(" ")[2] in " ".join(res.output.split()), res.output


def test_the_problem_section_is_laid_under_sweep_and_synth(work):
    """Issue 36: a run config states the settings sweep and synth share once, in ``problem:``;
    each section's own keys win. The run and the stage commands read the same options, and the
    run's record (its cache keys) is that of a config repeating them."""
    shared = {"T": 6, "eps_e": 0.05, "radius": 1.0, "measure": "position", "R": [10, 10, 1]}
    sweep = {"grid": {"S": [0.0, 0.01]}, "s_max_curve": False}
    synth = {"T": 8, "S": 0.01, "delta": 0.05, "radius": 3.0}
    folder = work / "cfg"
    once = _write(folder, problem=shared, sweep=sweep, synth=synth)
    cfg = load_run_config(once)
    assert cfg.sweep.T == 6 and cfg.synth.T == 8  # the section wins
    assert cfg.sweep.measure == cfg.synth.measure == "position"
    assert cfg.synth.R == cfg.sweep.R == [[10, 0, 0], [0, 10, 0], [0, 0, 1]]
    record = cfg.record()
    twice = folder / "twice.yaml"
    twice.write_text(yaml.safe_dump({**BASE, "sweep": {**shared, **sweep},
                                     "synth": {**shared, **synth}}, sort_keys=False))  # fmt: skip
    assert "problem" not in record and load_run_config(twice).record() == record
    # qsls synth --config reads its section with the problem under it
    res = _cli("synth", "--config", once, "--max-feasible-s")
    assert res.exit_code == 0, res.output
    assert re.search(r"T\s+│ 8 ", res.output)
    assert _cli("synth", "--config", twice, "--max-feasible-s").output == res.output
    # a misspelled key names the problem section
    bad = _write(folder, problem={"mesure": "full"}, synth=synth)
    with pytest.raises(
        ConfigError, match=r"problem: unknown option 'mesure'; did you mean 'measure'"
    ):
        load_run_config(bad)


def test_no_shipped_run_config_states_a_shared_setting_twice():
    """The configs state what sweep and synth share once, in ``problem:``: no problem field has
    the same value in both sections."""
    from pathlib import Path

    from qsls.pipeline.control.options import ProblemOptions

    configs = Path(__file__).resolve().parents[1] / "configs"
    twice = {}
    for path in sorted(configs.glob("*.yaml")):
        data = yaml.safe_load(path.read_text()) or {}
        sweep, synth = data.get("sweep") or {}, data.get("synth") or {}
        same = [k for k in ProblemOptions.model_fields if k in sweep and sweep[k] == synth.get(k)]
        if same:
            twice[path.name] = same
    assert twice == {}
