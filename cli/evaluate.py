"""Check certified bounds on held-out flights (``qsls fly`` flies the controllers)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer
from typer.core import TyperCommand

from qsls.cli.common import RichProgress, cli_errors, overrides, print_summary, print_verdicts
from qsls.cli.fields import model_options
from qsls.pipeline.evaluate.options import EvaluateOptions

EXAMPLE = "qsls evaluate --model fit --controller synth --flights flights/f3 --out ev"


class Command(TyperCommand):
    """For one release: ``qsls evaluate --fly ...`` says where the flying went, before its
    other (now unknown) options are parsed."""

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:  # Typer's own click Context
        if "--fly" in args:
            typer.echo(
                "error: 'qsls evaluate --fly' is now 'qsls fly' (the same options)", err=True
            )
            ctx.exit(2)
        return super().parse_args(ctx, args)


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
