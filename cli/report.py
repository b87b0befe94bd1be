"""``qsls report``: one self-contained HTML report (and Markdown) from a run folder."""

from __future__ import annotations

from pathlib import Path

import typer

from qsls.cli.common import RichProgress, cli_errors, print_summary

EXAMPLE = "qsls report runs/quickstart --out quickstart-report"


@cli_errors
def command(
    run_dir: Path = typer.Argument(..., help="Folder of a 'qsls run' (holds the stage folders)."),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="Report folder. Default: RUN_DIR/report."
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing report folder."),
) -> None:
    """Write a self-contained HTML report and report.md from a run folder."""
    from qsls.pipeline.report.stage import report

    with RichProgress() as progress:
        result = report(run_dir, out, force=force, progress=progress)
    print_summary("qsls report", result.summary())
