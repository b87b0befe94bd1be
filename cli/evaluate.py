"""Check certified bounds on held-out flights (``qsls fly`` flies the controllers)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import RichProgress, cli_errors, overrides, print_summary, print_verdicts
from qsls.cli.fields import model_options
from qsls.pipeline.evaluate.options import EvaluateOptions

EXAMPLE = "qsls evaluate --model fit --controller synth --flights flights/f3 --out ev"


def _moved(fly: bool) -> None:
    """For one release: ``qsls evaluate --fly`` says where the flying went, before any other
    option is checked."""
    if fly:
        typer.echo("error: 'qsls evaluate --fly' is now 'qsls fly' (the same options)", err=True)
        raise typer.Exit(2)


@cli_errors
@model_options(
    EvaluateOptions,
    {
        "smooth_s": ("--smooth-s",), "flown_by": ("--flown-by",),
        "state_scale": ("--state-scale",), "max_figure_flights": ("--max-figure-flights",),
    },
)  # fmt: skip
def command(
    model: Path = typer.Option(
        ...,
        "--model",
        help="Error model: error_model.yaml or the 'qsls fit' folder holding it "
        "(its training_states.parquet gives the distance to the training data).",
    ),
    controller: list[Path] = typer.Option(
        ...,
        "--controller",
        help="Controller folder written by 'qsls synth' (holds "
        "certificate.yaml), or a synth output folder for all its controllers. Repeatable.",
    ),
    flights: list[Path] = typer.Option(
        None,
        "--flights",
        help="Held-out flight folder written by 'qsls ingest'. Repeatable.",
    ),
    out: Path = typer.Option(
        ..., "--out", help="Output folder (evaluation.json, .parquet, figures)."
    ),
    config: Path = typer.Option(
        None, "--config", help="YAML file of options (the command line wins)."
    ),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the PNG figures."),
    force: bool = typer.Option(
        False, "--force", help="Overwrite --out; another error model's controller only warns."
    ),
    fly: bool = typer.Option(
        False, "--fly", hidden=True, is_eager=True, callback=lambda v: _moved(v), help="qsls fly."
    ),
    *,
    given: dict[str, Any],
) -> None:
    """Check the certified bounds on held-out flights (to fly the controllers: qsls fly)."""
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.evaluate.section import EvaluateSection

    figures = overrides(figures=False if no_figures else None)
    ov = {**given, **figures}
    section = load_options(EvaluateSection, config, ov, section="evaluate")
    from qsls.pipeline.evaluate.stage import evaluate

    with RichProgress() as progress:
        checked = evaluate(
            flights or [], model, controller, section.bound(), out, force=force, progress=progress
        )
    for w in checked.warnings:
        typer.echo(f"warning: {w}", err=True)
    print_summary("qsls evaluate", checked.summary())
    print_verdicts("Certified bound on the held-out flights", checked.verdicts())
