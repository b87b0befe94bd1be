"""--help from the options models: every stage option's help is its model field's docstring and
default (the model is the one source of both; tests/test_cli_options.py checks each option is
a field that defers to it), the models document their fields one way, flags are shown as flags, each
command shows an example, and --help fits 80 columns without one word per line."""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys

import pytest
import typer

from qsls.cli.fields import default_text, field_help, model_options
from qsls.cli.main import COMMANDS, app

# command -> (module:Model, {cli parameter: model field (dotted: nested), or None: not an
# option of the model (inputs, outputs, switches of the command itself)})
MODELS: dict[str, tuple[str, dict[str, str | None]]] = {
    "fit": (
        "qsls.pipeline.errormodel.fit:FitOptions",
        {"out": None, "config": None, "force": None, "no_figures": None},
    ),
    "synth": (
        "qsls.pipeline.control.synth:SynthOptions",
        {
            "model": None,
            "config": None,
            "out": None,
            "force": None,
            "max_feasible_s": None,
        },
    ),
    "sweep": (
        "qsls.pipeline.control.sweep:SweepSection",
        {
            "config": None,
            "out": None,
            "model": None,
            "force": None,
        },
    ),
    "ingest": (
        "qsls.pipeline.ingest.stage:IngestOptions",
        {"out": None, "config": None, "force": None},
    ),
    "replay": (
        "qsls.pipeline.export.options:ReplayOptions",
        {"out": None, "config": None, "force": None},
    ),
    "export": (
        "qsls.pipeline.export.options:ExportOptions",
        {"out": None, "config": None, "force": None},
    ),
    "simulate": (
        "qsls.pipeline.sim.simulate:SimOptions",
        {
            "out": None,
            "config": None,
            "force": None,
            "perception": "vio.perception",
            "vio": "vio.kind",
            "controller": "controller.kind",
            "fmt": "log.format",
            "backend": "controller.backend",
            "interface": "px4.interface",
        },
    ),
    "calibrate": (
        "qsls.pipeline.calibrate.options:CalibrateOptions",
        {
            "model": None,
            "controllers": None,
            "out": None,
            "config": None,
            "force": None,
            "only": "controllers",
            "recorded": "recorded.calibration",
            "recorded_range": "recorded.range",
            "recorded_validation": "recorded.validation",
            "mode": "monitor.mode",
            "false_trip_rate": "monitor.false_trip_rate",
        },
    ),
    "evaluate": (
        "qsls.pipeline.evaluate.options:EvaluateOptions",
        {
            "model": None,
            "controller": None,
            "flights": None,
            "out": None,
            "config": None,
            "force": None,
            "no_figures": None,
        },
    ),
    "fly": (
        "qsls.pipeline.fly.options:FlyOptions",
        {
            "model": None,
            "controller": None,
            "out": None,
            "config": None,
            "force": None,
            "no_figures": None,
            "backend": "sim.controller.backend",
        },
    ),
}


def _model(path: str):
    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)


def _field(model, dotted: str):
    """(the model holding the last part, the field name)."""
    *outer, last = dotted.split(".")
    for part in outer:
        model = model.model_fields[part].annotation
    return model, last


def _options(command: str):
    cmd = typer.main.get_command(app).commands[command]
    return [p for p in cmd.params if p.param_type_name == "option"]


@pytest.mark.parametrize("command", sorted(MODELS))
def test_every_options_help_states_the_models_default(command):
    model_path, names = MODELS[command]
    model = _model(model_path)
    problems = []
    for p in _options(command):
        if p.name == "help":
            continue
        dotted = names.get(p.name, p.name)
        if dotted is None:
            continue
        owner, field = _field(model, dotted)
        if field not in owner.model_fields:
            problems.append(f"--{p.name}: no field '{dotted}' in {model.__name__}")
            continue
        default = owner.model_fields[field].get_default(call_default_factory=True)
        if p.default is not None and not (p.is_flag and p.default is False and default is False):
            problems.append(f"--{p.name}: Typer default {p.default!r} (leave it to the model)")
        flags = (p.opts[0], p.secondary_opts[0]) if p.secondary_opts else None
        want = (
            f"(default: {default_text(owner, field, flags)})" if default is not None else "default"
        )
        if want not in " ".join((p.help or "").split()):
            problems.append(f"--{p.name}: help {p.help!r} does not say {want}")
        pair = (f"{p.opts[0]}/{p.secondary_opts[0]}",) if p.secondary_opts else ()
        if p.help != field_help(model, dotted, pair):
            problems.append(f"--{p.name}: help {p.help!r} is not the field's")
    assert problems == [], "\n".join(problems)


DOCUMENTED = (
    "qsls.pipeline.errormodel.fit:FitOptions",
    "qsls.pipeline.ingest.stage:IngestOptions",
    "qsls.pipeline.fly.options:FlyOptions",
    "qsls.pipeline.evaluate.options:EvaluateOptions",
)


def test_the_option_models_document_their_fields_one_way():
    """Fields are documented by attribute docstrings (``use_attribute_docstrings`` on the
    base model), so ``model_fields[f].description`` is the one lookup for every model."""
    from qsls.pipeline.control.sweep import SweepOptions
    from qsls.pipeline.control.synth import ProblemOptions

    for path in DOCUMENTED:
        model = _model(path)
        assert model.model_config.get("use_attribute_docstrings"), path
        missing = [f for f, info in model.model_fields.items() if not info.description]
        assert missing == [], f"{path}: undocumented {missing}"
    own = set(SweepOptions.model_fields) - set(ProblemOptions.model_fields)
    assert all(SweepOptions.model_fields[f].description for f in own)


def _help(*args: str) -> str:
    env = {**os.environ, "COLUMNS": "80", "TERM": "dumb"}
    out = subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", *args, "--help"],
        capture_output=True, text=True, env=env,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    return out.stdout


@pytest.mark.parametrize("command", [name for name, _ in COMMANDS])
def test_help_shows_flags_as_flags_an_example_and_fits_80_columns(command):
    text = _help(command)
    lines = text.splitlines()
    assert max(len(ln) for ln in lines) <= 80
    run = longest = 0  # consecutive lines holding a single word: text wrapped word by word
    for ln in lines:
        run = run + 1 if len(ln.split()) == 1 and not ln.strip().endswith(":") else 0
        longest = max(longest, run)
    assert longest < 3, text
    assert "--force <bool>" not in text and "<bool>" not in text
    assert "Example:" in text and f"qsls {command}" in text.split("Example:")[1]


def test_every_command_reads_its_section_of_one_config_file(tmp_path):
    """One YAML with a section per command (as a `qsls run` config): each command takes its
    own section; a file without the section is read whole."""
    both = tmp_path / "both.yaml"
    both.write_text(
        "name: x\n"
        "synth: {T: 6, S: 0.1, eps_e: 0.05, radius: 1.0, delta: 0.05}\n"
        "sweep: {eps_e: 0.05, radius: 1.0, delta: 0.05, s_max_curve: false,\n"
        "        grid: {S: [0.05, 1.5], T: [6]}}\n"
        "evaluate: {smooth_s: 0.5}\n"
        "fly: {seeds: [7]}\n"
    )

    def run(*args):
        env = {**os.environ, "COLUMNS": "200"}
        return subprocess.run(
            [sys.executable, "-m", "qsls.cli.main", *map(str, args)],
            capture_output=True, text=True, env=env,
        )  # fmt: skip

    synth = run("synth", "-c", both, "--max-feasible-s")
    assert synth.returncode == 0, synth.stderr
    assert re.search(r"T\s+│ 6 ", synth.stdout) and re.search(r"delta\s+│ 0.05 ", synth.stdout)
    sweep = run("sweep", "-c", both, "-o", tmp_path / "sw", "-j", "1")
    assert sweep.returncode == 0, sweep.stderr
    import pandas as pd

    assert list(pd.read_parquet(tmp_path / "sw" / "sweep.parquet")["S"]) == [0.05, 1.5]
    # the same options as a plain file (no sections): read whole
    flat = tmp_path / "flat.yaml"
    flat.write_text("T: 6\nS: 0.1\neps_e: 0.05\nradius: 1.0\ndelta: 0.05\n")
    again = run("synth", "-c", flat, "--max-feasible-s")
    assert again.returncode == 0 and again.stdout == synth.stdout
    # evaluate's section goes through the same reader: a bad value names the file
    bad = tmp_path / "bad.yaml"
    bad.write_text("evaluate: [1, 2]\n")
    ev = run("evaluate", "--model", tmp_path, "--controller", tmp_path, "--out", tmp_path / "e",
             "--config", bad)  # fmt: skip
    assert ev.returncode == 2 and "section 'evaluate' must be a mapping" in ev.stderr


def test_no_command_states_a_default_by_hand():
    """Issue 36: the options are built from the model's fields (``cli.fields``),
    which appends the model's default; a hand-written "(default: ...)" would drift from it.
    The models live in light modules (``*/options.py``), so building the options costs the
    command line no solver, generator or bag writer at start."""
    from pathlib import Path

    cli = Path(__file__).resolve().parents[1] / "cli"
    by_hand = {
        f.name: f.read_text().count("(default: ")
        for f in sorted(cli.glob("*.py"))
        if f.name not in ("common.py", "fields.py")
    }
    assert {k: v for k, v in by_hand.items() if v} == {}


def test_a_generated_option_takes_type_default_and_help_from_the_model():
    """Change a field's default and docstring in a subclass: the generated option shows both,
    reads the command line as the field's type, and leaves an option not given to the model."""
    from pydantic import Field
    from typer.testing import CliRunner

    from qsls.pipeline.control.options import SynthOptions
    from qsls.pipeline.core.config import load_options

    class Changed(SynthOptions):
        T: int = Field(7, ge=2, le=500)
        """Seven taps unless told."""

    seen = []

    @model_options(Changed, {"T": ("--T",), "R": ("--R",), "pd.kd": ("--kd",)})
    def command(*, given: dict) -> None:
        seen.append(load_options(Changed, None, given))

    small = typer.Typer()
    small.command()(command)
    option = {p.name: p for p in typer.main.get_command(small).params}
    assert option["T"].help == "Seven taps unless told. (default: 7)"
    assert option["T"].help == field_help(Changed, "T", ("--T",))
    assert option["R"].help.endswith("(default: 1,1,0.1)")
    runner = CliRunner()
    assert runner.invoke(small, []).exit_code == 0
    assert runner.invoke(small, ["--T", "9", "--R", "2,2,0.5", "--kd", "1,1,2"]).exit_code == 0
    assert runner.invoke(small, ["--T", "x"]).exit_code == 2  # an int, as the field
    default, given = seen
    assert (default.T, given.T) == (7, 9)
    assert given.R == [[2.0, 0, 0], [0, 2.0, 0], [0, 0, 0.5]] and given.pd.kd == (1, 1, 2)
    assert given.pd.kp == default.pd.kp  # the nested model's other fields stay its defaults


def test_synth_and_sweep_expose_the_same_problem_options():
    """The problem's options are declared once (cli/problem.py): both commands have each, with
    the same help where the field is the same."""
    from qsls.cli.problem import PROBLEM

    synth = {p.name: p for p in _options("synth")}
    sweep = {p.name: p for p in _options("sweep")}
    for name in PROBLEM:
        flags = synth[name].opts + synth[name].secondary_opts
        assert flags == sweep[name].opts + sweep[name].secondary_opts, name
        if name != "norm":  # synth's norm also takes both
            assert synth[name].help == sweep[name].help, name
