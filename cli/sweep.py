"""``qsls sweep``: a grid of robust syntheses, locally or on a Dask cluster."""

from __future__ import annotations

from pathlib import Path

import typer

from qsls.cli.common import cli_errors, print_summary


@cli_errors
def command(
    config: Path | None = typer.Option(
        None, "--config", "-c", help="YAML file: base synth options plus 'grid' (axis: [values])."
    ),
    out: Path = typer.Option(
        ..., "--out", "-o", help="Output folder (sweep.parquet, sweep.csv, figures)."
    ),
    model: Path | None = typer.Option(
        None,
        "--model",
        "-m",
        help="error_model.yaml or fit folder (needed when S/eps_e are names).",
    ),
    jobs: int | None = typer.Option(
        None, "--jobs", "-j", help="Local worker processes (default: all cores)."
    ),
    scheduler: str | None = typer.Option(
        None,
        "--scheduler",
        help="Dask scheduler address, e.g. tcp://127.0.0.1:8786 (instead of --jobs).",
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
) -> None:
    """A grid of robust syntheses (feasibility map), locally or on a Dask cluster."""
    from qsls.cli.common import RichProgress
    from qsls.pipeline.config import load_options
    from qsls.pipeline.errors import ConfigError
    from qsls.pipeline.sweep import SweepOptions, sweep

    if jobs is not None and scheduler is not None:
        raise ConfigError("give --jobs or --scheduler, not both")
    opts = load_options(SweepOptions, config, {})
    where = {"jobs": jobs, "scheduler": scheduler}
    with RichProgress() as progress:
        result = sweep(opts, out, error_model=model, force=force, progress=progress, **where)
    print_summary("sweep", result.summary())
