"""Fly the controllers side by side in simulation: every assumption checked, the paper's findings."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import (
    RichProgress,
    cli_errors,
    overrides,
    parse_list,
    print_summary,
    print_table,
    print_verdicts,
)
from qsls.cli.fields import Flag, Table, model_options
from qsls.pipeline.fly.options import FlyOptions

EXAMPLE = "qsls fly --model fit --controller synth --out fly --seeds 0,1,2"


def estimators(text: str, flag: str) -> str | list[str] | None:
    """``--vio``: one estimator, or a comma-separated list flown side by side."""
    return parse_list(text, flag, "value") if "," in text else text


FLY: Table = {
    "seeds": ("--seeds",),
    "duration": ("--duration",),
    "conditions": ("--conditions",),
    "jobs": ("--jobs",),
    "scheduler": ("--scheduler",),
    "wait_workers": ("--wait-workers",),
    "vio": Flag(("--vio",), parse=estimators),
    "sim.controller.backend": ("--backend",),
    "assured": ("--assured/--no-assured",),
    "fallback": ("--fallback",),
    "state_scale": ("--state-scale",),
    "max_figure_flights": ("--max-figure-flights",),
    "track_threshold_m": ("--track-threshold-m",),
    "tie_rel": ("--tie-rel",),
    "keep_bags": ("--keep-bags/--no-keep-bags",),
    "se3": ("--se3/--no-se3",),
}
"""The flying options ``qsls fly`` exposes."""

FLY_CONFIG_ONLY = {
    "sim": "the vehicle, reference and VIO: a run config's simulate: section",
    "ingest": "how each flight's log is ingested: the ingest: section",
    "controllers": "names; the command line gives --controller folders",
    "pd_z_control": "on, off or a list of controllers",
}
"""FlyOptions' fields a config file sets (mappings, or spelled by another parameter)."""


@cli_errors
@model_options(
    FlyOptions,
    {**FLY, "smooth_s": ("--smooth-s",)},
    config_only=FLY_CONFIG_ONLY,
)
def command(
    model: Path = typer.Option(
        ...,
        "--model",
        help="Error model: error_model.yaml or the 'qsls fit' folder holding it.",
    ),
    controller: list[Path] = typer.Option(
        ...,
        "--controller",
        help="Controller folder written by 'qsls synth' or 'qsls calibrate' (holds "
        "certificate.yaml), or a synth output folder for all its controllers. Repeatable.",
    ),
    out: Path = typer.Option(
        ...,
        "--out",
        help="Output folder (the flights, findings.json, comparison.md, figures).",
    ),
    config: Path = typer.Option(
        None,
        "--config",
        help="YAML file of options: its 'fly:' section, as in a run config (the command line "
        "wins).",
    ),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the PNG figures."),
    force: bool = typer.Option(
        False, "--force", help="Overwrite --out; another error model's controller only warns."
    ),
    *,
    given: dict[str, Any],
) -> None:
    """Fly the controllers side by side in simulation: every assumption checked, the paper's findings."""
    figures = overrides(figures=False if no_figures else None)
    fly(model, controller, out, config, force, {**given, **figures})


def fly(
    model: Path,
    controllers: list[Path],
    out: Path,
    config: Path | None,
    force: bool,
    given: dict[str, object],
) -> None:
    """Fly (the options: the config's ``fly:`` section, then ``given``), then the summary, the
    paper comparison and the verdicts."""
    from qsls.pipeline.fly.options import load_fly_options
    from qsls.pipeline.fly.stage import fly_evaluate

    options = load_fly_options(config, given)
    with RichProgress() as progress:
        result = fly_evaluate(model, controllers, options, out, force=force, progress=progress)
    print_summary("qsls fly", result.summary())
    cols, rows = result.comparison_rows()
    print_table("Against the paper's findings", cols, rows)
    print_verdicts("Certified bound on the flown flights", result.verdicts())
