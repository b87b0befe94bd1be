"""``qsls ingest``: flight logs (ROS1, ROS2, MCAP, TUM, EuRoC) onto one clock and one frame."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import cli_errors
from qsls.cli.fields import Flag, auto_or_number, model_options
from qsls.pipeline.ingest.options import IngestOptions

EXAMPLE = "qsls ingest --vio vio.tum --truth data.csv --out flights/f1 --dt 0.1"


@cli_errors
@model_options(
    IngestOptions,
    {
        "vio_topic": ("--vio-topic",),
        "truth_topic": ("--truth-topic",),
        "vio": ("--vio",),
        "truth": ("--truth",),
        "dt": ("--dt",),
        "align": ("--align",),
        "time_offset": Flag(("--time-offset",), parse=auto_or_number),
        "vio_velocity_frame": ("--vio-velocity-frame",),
        "stamp": ("--stamp",),
        "max_gap": ("--max-gap",),
        "truth_frame": ("--truth-frame",),
        "export_tum": ("--export-tum",),
        "max_time_offset": ("--max-time-offset",),
        "min_overlap": ("--min-overlap",),
        "velocity_window": ("--velocity-window",),
        "drop_nonfinite": ("--drop-nonfinite",),
        "mass": ("--mass",),
        "hover_thrust": ("--hover-thrust",),
        "reference": ("--reference",),
        "feedforward": ("--feedforward",),
        "commands_topic": ("--commands-topic",),
        "reference_topic": ("--reference-topic",),
        "max_truth_accel": ("--max-truth-accel",),
        "decoder": ("--decoder",),
    },
)
def command(
    sources: list[Path] = typer.Argument(
        None,
        help="Bags: ROS1 .bag, rosbag2 folder (or its .db3/.mcap), plain .mcap. VIO and truth "
        "may be in one bag or two.",
        show_default=False,
    ),
    out: Path = typer.Option(
        ..., "--out", "-o", help="Output folder (flight.parquet, manifest.json)."
    ),
    config: Path = typer.Option(
        None, "--config", "-c", help="YAML file with any of these options."
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
    *,
    given: dict[str, Any],
) -> None:
    """Put VIO estimates and ground truth on one clock, one frame and one dt grid."""
    _one_blas_thread()
    from qsls.cli.common import RichProgress, print_summary
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.ingest.stage import ingest

    options = load_options(IngestOptions, config, given, section="ingest")
    with RichProgress() as progress:
        result = ingest(list(sources or []), options, out, force=force, progress=progress)
    print_summary("qsls ingest", result.summary())
    for w in result.warnings:
        typer.echo(f"warning: {w}", err=True)


def _one_blas_thread() -> None:
    """Start numpy with OpenBLAS on one thread, as ingest runs it anyway (the input hash has
    the other core, :func:`qsls.pipeline.ingest.stage.ingest`): OpenBLAS otherwise starts a
    thread per core at load (35 ms of CPU) that ingest then idles. The variable is set only
    while numpy loads, and only when the user did not set it."""
    import os
    import sys

    if "numpy" in sys.modules or "OPENBLAS_NUM_THREADS" in os.environ:
        return
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    try:
        import numpy  # noqa: F401
    finally:
        del os.environ["OPENBLAS_NUM_THREADS"]
