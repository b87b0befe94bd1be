"""What a new user met (issue 26): bad numbers, unwritable folders, misnamed formats and
other inputs answered with one line and nothing left behind, through the public commands."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from qsls.cli.main import app

RUN = CliRunner()


def invoke(*args):
    return RUN.invoke(app, [str(a) for a in args])


def one_line(res, code: int = 2) -> str:
    """The single ``error:`` line of a refused command (no traceback)."""
    assert res.exit_code == code, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    lines = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, res.output
    return lines[0]


# --------------------------------------------------------------------------- item 6
@pytest.mark.parametrize(
    "args, field, value",
    [
        (["ingest", "--vio", "v.txt", "--truth", "t.txt", "--time-offset", "nan"], "time_offset", "nan"),
        (["ingest", "--vio", "v.txt", "--truth", "t.txt", "--time-offset", "inf"], "time_offset", "inf"),
        (["synth", "--S", "nan"], "S", "nan"),
        (["synth", "--eps-e", "nan"], "eps_e", "nan"),
        (["synth", "--delta", "nan"], "delta", "nan"),
        (["synth", "--dt", "inf"], "dt", "inf"),
        (["synth", "--S", "-inf"], "S", "-inf"),
    ],
)  # fmt: skip
def test_non_finite_numbers_are_refused_by_the_options_model(tmp_path, args, field, value):
    res = invoke(*args, "--out", tmp_path / "out")
    assert one_line(res) == f"error: options: '{field}': must be a finite number (got {value})"
    assert not (tmp_path / "out").exists()


def test_non_finite_numbers_in_a_config_file_or_a_list_are_refused(tmp_path):
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.core.errors import ConfigError
    from qsls.pipeline.export.replay import ReplayOptions

    cfg = tmp_path / "replay.yaml"
    cfg.write_text("replay:\n  thrust_band: [0.5, .inf]\n")
    with pytest.raises(ConfigError, match=r"'thrust_band': must be a finite number"):
        load_options(ReplayOptions, cfg, section="replay")
    cfg.write_text("replay:\n  max_gap: .nan\n")
    with pytest.raises(ConfigError, match=r"'max_gap': must be a finite number \(got nan\)"):
        load_options(ReplayOptions, cfg, section="replay")


# --------------------------------------------------------------------------- item 1
def test_an_output_containing_the_config_file_is_refused_even_with_force(tmp_path):
    from tests.test_fit import vio_flights

    flights, _ = vio_flights(tmp_path / "flights", n=1)
    folder = tmp_path / "d"
    folder.mkdir()
    cfg = folder / "fit.yaml"
    cfg.write_text("fit:\n  radius: 1.0\n  figures: false\n")
    before = cfg.read_bytes()
    res = invoke("fit", *flights, "--config", cfg, "--out", folder, "--force")
    assert one_line(res) == (
        f"error: output folder {folder} contains the input {cfg}; writing it would destroy the "
        "input (even with --force): choose an output folder apart from the inputs"
    )
    assert cfg.read_bytes() == before and sorted(p.name for p in folder.iterdir()) == ["fit.yaml"]
    # the same file, kept apart from the output, is read as usual
    assert invoke("fit", *flights, "--config", cfg, "--out", tmp_path / "fit").exit_code == 0
