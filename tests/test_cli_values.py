"""Values given on the command line (issue 35): refused in one line naming the flag (not the
config file beside it), absurd sizes refused before any work, an empty list never silently
the default."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from qsls.cli.main import app

runner = CliRunner()


def _refused(args: list[str], *expect: str, absent: str = "") -> str:
    res = runner.invoke(app, args)
    text = res.output.strip()
    assert res.exit_code != 0 and text.startswith("error: ") and "\n" not in text, text
    for e in expect:
        assert e in text, text
    if absent:
        assert absent not in text, text
    return text


def test_a_bad_command_line_value_is_blamed_on_its_flag_not_the_config(tmp_path):
    cfg = tmp_path / "fix.yaml"
    cfg.write_text("m: 1\n")
    out = str(tmp_path / "o")
    _refused(["synth", "--config", str(cfg), "--m", "2.5", "--out", out],
             "command line: 'm': must be a whole number >= 0 or 'auto'",
             absent="fix.yaml")  # fmt: skip
    cfg.write_text("m: 2.5\n")  # the file's own mistake is the file's
    _refused(["synth", "--config", str(cfg), "--out", out], "fix.yaml: 'm': must be a whole")


def test_negative_m_and_a_short_error_scale_are_refused(tmp_path):
    out = str(tmp_path / "o")
    _refused(["synth", "--m", "-1", "--out", out], "'m': must be a whole number >= 0")
    _refused(["synth", "--error-scale", "1,1,1,1,1", "--out", out],
             "'error_scale': needs 6 weights (x, y, z, vx, vy, vz), got 5")  # fmt: skip


def test_an_empty_seed_list_is_refused(tmp_path):
    _refused(
        ["fly", "--model", str(tmp_path), "--controller", str(tmp_path),
         "--seeds", "", "--out", str(tmp_path / "o")],
        "--seeds: empty list",
    )  # fmt: skip


def test_an_absurd_simulation_length_is_refused_at_once(tmp_path):
    _refused(["simulate", "--duration", "1e9", "--out", str(tmp_path / "s")], "duration")
    assert not (tmp_path / "s").exists()


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    from tests.bagfixtures import write_flight

    return write_flight(tmp_path_factory.mktemp("b") / "f.bag", "ros1", duration=12.0)


def test_a_dt_far_finer_than_the_data_is_refused(tmp_path, bag):
    out = tmp_path / "o"
    _refused(["ingest", str(bag), "--dt", "1e-6", "--out", str(out)],
             "times finer than the VIO's own sampling step", "choose --dt of at least")  # fmt: skip
    assert not out.exists()
    res = runner.invoke(app, ["ingest", str(bag), "--dt", "0.01", "--out", str(out)])
    assert res.exit_code == 0, res.output


def test_help_texts_say_what_the_commands_do():
    """Issue 35: export --help said '(default: c) [required]', replay's example was refused,
    run --help left fly out of --from, the README's topics were not the simulated bags'."""
    import re

    from qsls.cli import replay
    from qsls.pipeline.sim.options import LogOptions

    export = runner.invoke(app, ["export", "--help"], terminal_width=200).output
    target = next(ln for ln in export.splitlines() if "--target" in ln)
    assert "(default: c)" in target and "[required]" not in target
    run = " ".join(runner.invoke(app, ["run", "--help"], terminal_width=200).output.split())
    assert re.search(r"--from.*evaluate, fly or report", run)
    assert replay.EXAMPLE.split("--out ")[1].split()[0].endswith(".mcap")
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert "--vio-topic /vio/odom " not in readme
    assert f"--vio-topic {LogOptions().vio_topic} " in readme
    assert f"--truth-topic {LogOptions().mocap_topic} " in readme


def test_sweep_takes_eps_w_max_as_synth_does(tmp_path):
    """Issue 35: sweep's --eps-w refused 'max', which synth accepts."""
    from qsls.pipeline.core.artifacts import dump_yaml
    from qsls.pipeline.errormodel.model import DisturbanceStats, ErrorModel, SlopeStats

    em = ErrorModel(
        disturbance=DisturbanceStats(max=0.01, source="inputs", n_steps=100),
        eps_e=0.05, eps_e_percentiles={"p95": 0.04}, radius=1.0,
        s_slope=SlopeStats(max=0.13, percentiles={"p50": 0.1, "p95": 0.12}),
        R0=0.05, delta=0.05, n_samples=100, n_pairs=1000,
    )  # fmt: skip
    (tmp_path / "fit").mkdir()
    (tmp_path / "fit" / "error_model.yaml").write_text(dump_yaml(em))
    res = runner.invoke(app, ["sweep", "--model", str(tmp_path / "fit"), "--eps-w", "max",
                              "-g", "T=6", "-g", "S=0.05", "--jobs", "1",
                              "--out", str(tmp_path / "o")])  # fmt: skip
    assert res.exit_code == 0, res.output
    import pandas as pd

    assert (pd.read_parquet(tmp_path / "o" / "sweep.parquet")["eps_w_value"] == 0.01).all()


def test_fly_takes_assured_and_fallback_from_its_model(tmp_path):
    """Issue 33's leftover: qsls fly --assured/--no-assured and --fallback pd|hold, built from
    FlyOptions (their defaults there), refused in one line naming the option."""
    from qsls.pipeline.fly.options import FlyOptions

    text = " ".join(runner.invoke(app, ["fly", "--help"], terminal_width=200).output.split())
    assured = "--no-assured" if not FlyOptions().assured else "--assured"
    assert "--assured / --no-assured" in text and f"(default: {assured})" in text
    assert f"(default: {FlyOptions().fallback})" in text.split("--fallback")[1]
    _refused(["fly", "--model", str(tmp_path), "--controller", str(tmp_path), "--out",
              str(tmp_path / "o"), "--assured", "--fallback", "land"],
             "'fallback': Input should be 'pd' or 'hold'")  # fmt: skip
    assert not (tmp_path / "o").exists()
