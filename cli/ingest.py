"""``qsls ingest``: flight logs (ROS1, ROS2, MCAP, TUM, EuRoC) onto one clock and one frame."""

from __future__ import annotations

from pathlib import Path

import typer

from qsls.cli.common import cli_errors, model_option, overrides
from qsls.pipeline.ingest.options import IngestOptions

EXAMPLE = "qsls ingest --vio vio.tum --truth data.csv --out flights/f1 --dt 0.1"


@cli_errors
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
    vio_topic: str = model_option(
        IngestOptions, "vio_topic", none="chosen when unambiguous",
        help="VIO topic (nav_msgs/Odometry, or a pose topic).",
    ),
    truth_topic: str = model_option(
        IngestOptions, "truth_topic", none="chosen when unambiguous",
        help="Ground-truth topic (PoseStamped, PoseWithCovarianceStamped, TransformStamped, Odometry, "
        "or a TF topic with --truth-frame).",
    ),
    vio: Path = model_option(
        IngestOptions, "vio", none="the SOURCES",
        help="File with the VIO stream: a bag, or a TUM trajectory.",
    ),
    truth: Path = model_option(
        IngestOptions, "truth", none="the SOURCES",
        help="File with the truth stream: a bag, a TUM file or a EuRoC csv.",
    ),
    dt: float = model_option(IngestOptions, "dt", help="Resampling period in seconds."),
    align: str = model_option(
        IngestOptions, "align",
        help="Frame alignment of the VIO to the truth: 4dof (yaw + translation), se3, none.",
    ),
    time_offset: str = model_option(
        IngestOptions, "time_offset",
        help="Seconds added to truth stamps to put them on the VIO clock, or 'auto' to estimate it.",
    ),
    vio_velocity_frame: str = model_option(
        IngestOptions, "vio_velocity_frame",
        help="Frame of the Odometry twist: body (ROS convention) or world (VINS-style).",
    ),
    stamp: str = model_option(
        IngestOptions, "stamp",
        help="Time of a message: header stamp or bag log time.",
    ),
    max_gap: float = model_option(
        IngestOptions, "max_gap",
        help="Never interpolate across a gap longer than this, in seconds.",
    ),
    truth_frame: str = model_option(
        IngestOptions, "truth_frame", none="none; a TF-only bag lists them",
        help="PARENT/CHILD transform of a TF topic.",
    ),
    export_tum: bool = model_option(
        IngestOptions, "export_tum", "--export-tum",
        help="Also write both aligned trajectories as TUM files (for evo).",
    ),
    max_time_offset: float = model_option(
        IngestOptions, "max_time_offset",
        help="Search range of --time-offset auto, in seconds.",
    ),
    min_overlap: float = model_option(
        IngestOptions, "min_overlap",
        help="Least common time of the two streams, in seconds.",
    ),
    velocity_window: float = model_option(
        IngestOptions, "velocity_window",
        help="Window of the smoothing differentiator, in seconds.",
    ),
    drop_nonfinite: bool = model_option(
        IngestOptions, "drop_nonfinite", "--drop-nonfinite",
        help="Skip messages with NaN/inf values instead of stopping.",
    ),
    config: Path = typer.Option(
        None, "--config", "-c", help="YAML file with any of these options."
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
) -> None:
    """Put VIO estimates and ground truth on one clock, one frame and one dt grid."""
    _one_blas_thread()
    from qsls.cli.common import RichProgress, print_summary
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.ingest.stage import IngestOptions, ingest

    given = overrides(
        vio_topic=vio_topic,
        truth_topic=truth_topic,
        vio=vio,
        truth=truth,
        dt=dt,
        align=align,
        time_offset=_offset(time_offset),
        vio_velocity_frame=vio_velocity_frame,
        stamp=stamp,
        max_gap=max_gap,
        truth_frame=truth_frame,
        export_tum=export_tum,
        max_time_offset=max_time_offset,
        min_overlap=min_overlap,
        velocity_window=velocity_window,
        drop_nonfinite=drop_nonfinite,
    )
    options = load_options(IngestOptions, config, given, section="ingest")
    with RichProgress() as progress:
        result = ingest(list(sources or []), options, out, force=force, progress=progress)
    print_summary("qsls ingest", result.summary())


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


def _offset(value: str | None) -> str | float | None:
    if value is None or value.strip().lower() == "auto":
        return None if value is None else "auto"
    try:
        return float(value)
    except ValueError:
        from qsls.pipeline.core.errors import ConfigError

        raise ConfigError(
            f"--time-offset: expected 'auto' or a number of seconds, got {value!r}"
        ) from None
