"""One YAML section, two readers: a ``qsls run`` config's ``sweep:`` and ``evaluate:`` sections
(with the keys that say where and how to run: ``jobs``, ``scheduler``, ``wait_workers``,
``fly``) work unchanged for the stage command with ``--config``, and the other way round; a
misspelled key is the same one-line error from both."""

from __future__ import annotations

import json

import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.control.sweep import SweepSection
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.run.runner import load_run_config, plan, run
from tests.test_runner_direct import BASE, _flights

SWEEP = {"grid": {"S": [0.0, 0.01]}, "T": 6, "eps_e": 0.05, "radius": 1.0, "s_max_curve": False, "jobs": 2}
EVALUATE = {"figures": False, "smooth_s": 0.5, "fly": {"seeds": [3], "jobs": 1, "duration": 5}}


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


def test_the_evaluate_section_with_fly_is_read_the_same_by_both(work):
    cfg = _write(work / "cfg", evaluate=EVALUATE)
    graph = plan(load_run_config(cfg), cfg, work / "out")
    by = {s.id: s.options for s in graph.stages}
    bound, fly = by["evaluate"], by["fly"]
    assert (bound.figures, bound.smooth_s) == (False, 0.5)
    # fly inherits the section's keys and adds its own
    assert (fly.figures, fly.smooth_s, fly.seeds, fly.jobs, fly.duration) == (
        False, 0.5, [3], 1, 5.0
    )  # fmt: skip
    # the stage command on the same file: the bound check with the section's options
    ran = run(_write(work / "cfg", evaluate=EVALUATE, stages=["ingest", "fit", "synth"]),
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
