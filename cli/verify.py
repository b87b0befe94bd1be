"""``qsls verify``: a calibration's certificates recomputed from their evidence (docs/verify.md)."""

from __future__ import annotations

from pathlib import Path

import typer

from qsls.cli.common import cli_errors

EXAMPLE = "qsls verify runs/quickstart/calibrate"


@cli_errors
def command(
    folder: Path = typer.Argument(
        ...,
        help="A calibration output ('qsls calibrate') or one controller folder inside it.",
    ),
) -> None:
    """Recompute every score, lambda_hat, the tested range and the numbers from the tick logs."""
    from qsls.pipeline.calibrate.verify import verify

    result = verify(folder)
    for line in result.lines():
        typer.echo(line)
    if not result.verified:
        raise typer.Exit(1)
