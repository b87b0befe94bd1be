"""What the console says (issue 50, words and warnings): ``--from`` names every stage, a
misspelled config section is named with the one meant, an uncertified controller is not said
to be "certified against" a model, the refusal leads with its fix, and ``qsls fit`` without a
reference warns that ``Delta`` is 0 (the library returns the warning, the CLI prints it)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.core.errors import ConfigError, InputError


def test_from_names_every_stage_of_a_run():
    from qsls.cli.run import STAGES
    from qsls.pipeline.run.runner import STAGE_ORDER

    assert set(STAGES) == {*STAGE_ORDER, "fly"}
    res = CliRunner().invoke(app, ["run", "--help"], env={"COLUMNS": "200"})
    assert "calibrate" in res.output.split("--from", 1)[1].split("\n\n")[0]


@pytest.mark.parametrize(("typo", "section"), [("synht", "synth"), ("fitt", "fit"),
                                               ("calibrat", "calibrate")])  # fmt: skip
def test_a_misspelled_section_is_named_with_the_one_meant(tmp_path, typo, section):
    from qsls.pipeline.core.config import read_section

    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"{typo}: {{T: 10}}\n")
    with pytest.raises(ConfigError, match=rf"section '{typo}': did you mean '{section}'\?"):
        read_section(cfg, section)
    cfg.write_text(f"{section}: {{T: 10}}\n")
    assert read_section(cfg, section) == {"T": 10}


def test_an_uncertified_controller_is_designed_not_certified_against_a_model(tmp_path):
    from qsls.pipeline.control.status import CERTIFIED, RELAXED
    from qsls.pipeline.evaluate.certified import check_model_hash
    from tests.test_certified_direct import BOUND

    model = tmp_path / "fit" / "error_model.yaml"
    model.parent.mkdir()
    model.write_text("eps_e: 0.05\n")
    relaxed = dataclasses.replace(BOUND, status=RELAXED, model_sha256="0" * 64)
    with pytest.raises(InputError) as err:
        check_model_hash(relaxed, model, force=False)
    text = str(err.value)
    assert "certified" not in text and "designed against error model 000000000000" in text
    assert text.index("pass the error model") < text.index("against error model")  # fix first
    warned = check_model_hash(relaxed, model, force=True)
    assert "designed against" in warned and "certified" not in warned
    certified = dataclasses.replace(BOUND, status=CERTIFIED, model_sha256="0" * 64)
    with pytest.raises(InputError, match="certified against error model"):
        check_model_hash(certified, model, force=False)


def test_stage_lines_show_the_stages_own_time():
    from qsls.cli.run import stage_line

    line = stage_line("calibrate", "ran", 13, 16, "", 19.4, 29.7)
    assert line is not None and "(  19.4 s, 29.7 s in all)" in line


@pytest.fixture(scope="module")
def flight(quickstart_session) -> Path:
    return quickstart_session[0] / "runs" / "quickstart" / "ingest" / "train_1"


def test_fit_without_a_reference_warns_that_delta_is_zero(flight, tmp_path):
    from qsls.pipeline.core.artifacts import read_manifest
    from qsls.pipeline.errormodel.fit import NO_REFERENCE, FitOptions, fit

    res = fit([flight], FitOptions(radius=1.0, figures=False), tmp_path / "a")
    assert res.model.delta == 0.0 and res.warnings == (NO_REFERENCE,)
    assert "--reference" in NO_REFERENCE and "Delta" in NO_REFERENCE
    assert read_manifest(tmp_path / "a")["results"]["warnings"] == [NO_REFERENCE]
    ref = "circle:radius=1.0,height=1.0,period=5.0"
    res = fit([flight], FitOptions(radius=1.0, figures=False, reference=ref), tmp_path / "b")
    assert res.model.delta > 0 and res.warnings == ()
    out = CliRunner().invoke(app, ["fit", str(flight), "--radius", "1", "--no-figures",
                                   "--out", str(tmp_path / "c")])  # fmt: skip
    assert out.exit_code == 0, out.output
    assert [ln for ln in out.output.splitlines() if ln.startswith("warning:")] == [
        f"warning: {NO_REFERENCE}"
    ]
