"""Input that reached a traceback, a MemoryError or a hang (issue 50, medium and low): an
output folder that is the current folder, a parent of it or the root; seeds below 0 or beyond
64 bits; counts and durations without an upper bound; a YAML alias bomb inside a certificate;
options the command line did not know although qsls's own messages name them. Each is one
line and a non-zero exit, or the right behaviour."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.core.artifacts import check_output, load_yaml
from qsls.pipeline.core.config import MAX_FLIGHTS, MAX_SEED, validate
from qsls.pipeline.core.errors import ConfigError, InputError

RUNNER = CliRunner()


def _refusal(args: list[str]) -> str:
    """The one ``error:`` line of a refused command (exit 2, no traceback)."""
    res = RUNNER.invoke(app, args)
    assert res.exit_code == 2, (res.exit_code, res.output, res.exception)
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    return lines[0]


# --------------------------------------------------------------------------- outputs in use
@pytest.mark.parametrize(
    ("out", "why"),
    [
        (".", "is the current folder"),
        ("./", "is the current folder"),
        ("sub/..", "is the current folder"),
        ("..", "holds the current folder"),
        ("/", "is the filesystem's root"),
        ("~", "is your home folder"),
    ],
)
def test_an_output_that_is_a_folder_in_use_is_refused(tmp_path, monkeypatch, out, why):
    work = tmp_path / "a" / "b"
    (work / "sub").mkdir(parents=True)
    monkeypatch.chdir(work)
    given = os.path.expanduser(out)
    for force in (False, True):
        with pytest.raises(InputError, match=why):
            check_output(Path(given), force)
    line = _refusal(["ingest", "x.bag", "--out", given, "--force"])
    assert why in line and "name a new folder" in line
    assert sorted(p.name for p in work.iterdir()) == ["sub"]  # nothing written, nothing locked


def test_a_named_new_folder_beside_the_current_one_is_fine(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    check_output(Path("out"), False)
    check_output(Path("../sibling"), False)


# --------------------------------------------------------------------------- seeds and counts
@pytest.mark.parametrize(
    ("model", "data", "expect"),
    [
        ("FlyOptions", {"seeds": [-5]}, "greater than or equal to 0"),
        ("FlyOptions", {"seeds": [0, MAX_SEED + 1]}, "seeds are stored in 64 bits"),
        ("FlyOptions", {"seeds": [2**70]}, "seeds are stored in 64 bits"),
        ("FlyOptions", {"seeds": list(range(MAX_FLIGHTS + 1))}, "at most 10000 items"),
        ("FlyOptions", {"duration": 1e12}, "a day"),
        ("CalibrateOptions", {"flights": 1_000_000_000}, "a certificate needs 19"),
        ("CalibrateOptions", {"validation": 300_000_000}, "a certificate needs 19"),
        ("CalibrateOptions", {"range_flights": MAX_FLIGHTS + 1}, "hours of flying"),
        ("CalibrateOptions", {"seed": -1}, "greater than or equal to 0"),
        ("CalibrateOptions", {"validation_seed": 2**64}, "64 bits"),
        ("CalibrateOptions", {"alpha": float("nan")}, "finite"),
        ("CalibrateOptions", {"alpha": -0.1}, "greater than 0"),
        ("CalibrateOptions", {"tube": float("inf")}, "finite"),
    ],
)
def test_seeds_counts_and_numbers_are_refused_when_read(model, data, expect):
    from qsls.pipeline.calibrate import options as calibrate_options
    from qsls.pipeline.fly import options

    with pytest.raises(ConfigError, match=expect) as err:
        validate(getattr(options, model, None) or getattr(calibrate_options, model), data)
    assert len(str(err.value)) < 300  # a 10 001-item list is not repeated back whole


@pytest.mark.parametrize("value", [2**32, 10**30])
def test_every_seed_of_every_model_is_bounded(value):
    """The simulator's, the fit's, the export's and a run's seed: one rule."""
    from qsls.pipeline.errormodel.options import FitOptions
    from qsls.pipeline.export.options import ExportOptions
    from qsls.pipeline.run.runconfig import RunConfig
    from qsls.pipeline.sim.options import SimOptions

    for model, data in (
        (SimOptions, {"seed": value}),
        (FitOptions, {"seed": value}),
        (ExportOptions, {"seed": value}),
        (RunConfig, {"name": "x", "seed": value}),
    ):
        with pytest.raises(ConfigError, match="64 bits"):
            validate(model, data)
        with pytest.raises(ConfigError, match="greater than or equal to 0"):
            validate(model, {**data, "seed": -5})


def test_fly_with_a_negative_or_huge_seed_is_one_line_before_flying(tmp_path):
    for seeds in ("-5", "0,18446744073709551617"):
        line = _refusal(["fly", "--model", str(tmp_path / "m"), "--controller",
                         str(tmp_path / "c"), "--out", str(tmp_path / "o"), "--seeds", seeds])  # fmt: skip
        assert "'seeds." in line
    assert not (tmp_path / "o").exists()


def test_calibrate_with_a_billion_flights_is_one_line(tmp_path):
    line = _refusal(["calibrate", "--model", str(tmp_path / "m"), "--controllers",
                     str(tmp_path / "c"), "--out", str(tmp_path / "o"), "--flights",
                     "1000000000"])  # fmt: skip
    assert "'flights'" in line and "at most 10000" in line


# --------------------------------------------------------------------------- YAML alias bombs
def _bomb(levels: int = 9) -> list[str]:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{k}: &a{k} [{', '.join([f'*a{k - 1}'] * 9)}]" for k in range(1, levels + 1)]
    return lines


def test_a_yaml_alias_bomb_in_an_artifact_is_refused_at_once():
    text = "calibration:\n  conditions:\n" + "".join(f"    {ln}\n" for ln in _bomb())
    text += "    bomb: *a9\n"
    assert len(text) < 1500
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="expands to more than"):
        load_yaml(text, "certificate.yaml")
    assert time.perf_counter() - t0 < 5
    # aliases that expand modestly (a few shared lists) are YAML as written: still read
    small = "a: &a [1, 2, 3]\nb: *a\nc: *a\n"
    assert load_yaml(small) == {"a": [1, 2, 3], "b": [1, 2, 3], "c": [1, 2, 3]}


def test_an_exported_certificate_with_an_alias_bomb_is_refused(tmp_path):
    """The issue's case: the bomb nested in ``calibration.conditions`` kept export busy over
    120 s; the certificate's reader now refuses it in one line."""
    from tests.controllerfixtures import synthesized

    ctrl = synthesized(calibrated=tmp_path / "c")
    cert = ctrl.folder / "certificate.yaml"
    text = cert.read_text()
    head = "  conditions: {perception: regular, stand_in: true}\n"
    assert head in text
    nested = "  conditions:\n    perception: regular\n"
    nested += "".join(f"    {ln}\n" for ln in _bomb()) + "    bomb: *a9\n"
    cert.write_text(text.replace(head, nested, 1))
    t0 = time.perf_counter()
    line = _refusal(["export", str(ctrl.folder), "--target", "python", "--out",
                     str(tmp_path / "x")])  # fmt: skip
    assert "expands to more than" in line and "aliases" in line
    assert time.perf_counter() - t0 < 30


# --------------------------------------------------------------------------- every option
def test_every_field_of_a_commands_model_is_an_option_or_named_config_only():
    """``qsls fit --inputs`` (named by the EuRoC certificate's ``status_reason`` and
    docs/guarantee.md), ``--environments`` and ``qsls synth --plant`` were refused as unknown:
    every field of the model is now an option, or listed as config-only in ``--help``."""
    import typer

    from qsls.cli.fields import CONFIG_ONLY
    from tests.test_cli_help import MODELS, _model

    problems = []
    commands = typer.main.get_command(app).commands
    for command, (path, names) in MODELS.items():
        cmd = commands[command]
        exposed = {(names.get(p.name) or p.name).split(".")[0] for p in cmd.params}
        exposed |= {"figures"}  # --no-figures, the command's own switch
        only = getattr(cmd.callback, CONFIG_ONLY, None) or {}
        listed = {k.strip() for key in only for k in key.split(",")}
        missing = sorted(set(_model(path).model_fields) - exposed - listed)
        if missing:
            problems.append(f"qsls {command}: {missing} neither options nor config-only")
        if only:
            assert "Config file only (--config)" in (cmd.epilog or ""), command
    assert problems == [], "\n".join(problems)


@pytest.mark.parametrize(
    "args",
    [
        ["fit", "--inputs", "a.parquet,b.parquet", "--plant", "nosuch"],
        ["fit", "--environments", "room1", "--environments", "room2", "--plant", "nosuch"],
        ["synth", "--plant", "nosuch"],
        ["sweep", "--radius", "1", "--plant", "nosuch"],
    ],
)
def test_the_options_qsls_names_are_taken(tmp_path, args):
    """Taken by the command line and handed to the model, whose rule then refuses the bad
    ``plant`` in one line naming it (an unknown option would be Click's usage error)."""
    line = _refusal([*args, "--out", str(tmp_path / "o")])
    assert "'plant'" in line and "No such option" not in line
