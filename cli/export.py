"""``qsls export``: a certified controller as C99 (header + source) or a stdlib Python module."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import cli_errors, print_summary
from qsls.cli.fields import model_options
from qsls.pipeline.export.options import ExportOptions

EXAMPLE = "qsls export controllers/l1_robust --target c --out export"


@cli_errors
@model_options(
    ExportOptions,
    {
        "target": ("--target", "-t"),
        "precision": ("--precision",),
        "prefix": ("--prefix",),
        "allow_uncertified": ("--allow-uncertified",),
        "verify_ticks": ("--verify-ticks",),
        "tilt_limit_deg": ("--tilt-limit-deg",),
        "thrust_limits": ("--thrust-limits",),
        "closed_loop_ticks": ("--closed-loop-ticks",),
        "seed": ("--seed",),
        "compiler": ("--compiler",),
    },
)
def command(
    controller: Path = typer.Argument(
        ..., help="Controller folder written by 'qsls synth' (controller.npz + certificate.yaml)."
    ),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder for the generated files."),
    config: Path | None = typer.Option(None, "--config", help="YAML file of export options."),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
    *,
    given: dict[str, Any],
) -> None:
    """Export a certified controller as C99 or a stdlib Python module, checked against Python."""
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.export.stage import export

    options = load_options(ExportOptions, config, given, section="export")
    result = export(controller, options, out, force=force)
    print_summary("qsls export", result.summary())
