"""``qsls fit``: the perception error model (eps_e, S-slope, delta) of ingested flights."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import cli_errors, overrides
from qsls.cli.fields import Flag, as_given, auto_or_number, model_options, repeated_list
from qsls.pipeline.errormodel.options import FitOptions

EXAMPLE = "qsls fit flights/f1 flights/f2 --out fit --radius 1.0"


@cli_errors
@model_options(
    FitOptions,
    {
        "radius": ("--radius", "-r"),
        "percentiles": ("--percentiles",),
        "min_separation": Flag(("--min-separation",), parse=auto_or_number),
        "state_scale": ("--state-scale",),
        "exclude_outliers": ("--exclude-outliers/--keep-outliers",),
        "outlier_z": ("--outlier-z",),
        "skip_start": ("--skip-start",),
        "reference": Flag(("--reference",), parse=as_given),
        "reference_lead_in": ("--reference-lead-in/--reference-pattern-only",),
        "r0": Flag(("--r0",), parse=as_given),
        "bootstrap": ("--bootstrap",),
        "bootstrap_block": ("--bootstrap-block",),
        "seed": ("--seed",),
        "jobs": ("--jobs", "-j"),
        "inputs": Flag(("--inputs",), parse=repeated_list, kind=list[str]),
        "environments": Flag(("--environments",), parse=repeated_list, kind=list[str]),
        "mass": ("--mass",),
        "plant": ("--plant",),
        "min_separation_factor": ("--min-separation-factor",),
        "reference_dt": ("--reference-dt",),
        "bootstrap_level": ("--bootstrap-level",),
        "top_pairs": ("--top-pairs",),
    },
)
def command(
    flights: list[Path] = typer.Argument(
        None,
        help="Flight folders written by 'qsls ingest' (the training data).",
        show_default=False,
    ),
    out: Path = typer.Option(
        ..., "--out", "-o", help="Output folder (error_model.yaml, training_states.parquet, PNGs)."
    ),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the PNG figures."),
    config: Path = typer.Option(
        None, "--config", "-c", help="YAML file of these options (its 'fit' section, or all)."
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
    *,
    given: dict[str, Any],
) -> None:
    """Estimate the perception error model (eps_e, S-slope, delta) from ingested flights."""
    from qsls.cli.common import RichProgress, print_summary
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.errormodel.fit import fit

    given = {**given, **overrides(figures=False if no_figures else None)}
    options = load_options(FitOptions, config, given, section="fit")
    with RichProgress() as progress:
        result = fit(list(flights or []), options, out, force=force, progress=progress)
    print_summary("qsls fit", result.summary())
    _print_worst_pairs(result.model.worst_pairs[:5])
    for w in result.warnings:
        typer.echo(f"warning: {w}", err=True)


def _print_worst_pairs(wp: list) -> None:
    from qsls.cli.common import print_table

    if not wp:
        return
    print_table(
        "Largest slopes (the pairs that set S)",
        ["slope", "distance", "flight i", "t_i", "flight j", "t_j", "||e_i - e_j||"],
        [
            (
                w.slope,
                w.distance,
                w.flight,
                round(w.t_i, 3),
                w.flight_j or w.flight,
                round(w.t_j, 3),
                max(abs(a - b) for a, b in zip(w.e_i, w.e_j, strict=True)),
            )
            for w in wp
        ],
    )
