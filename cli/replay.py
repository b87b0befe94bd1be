"""``qsls replay``: a recorded VIO stream through the exported controller, commands to an MCAP."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import cli_errors, print_summary
from qsls.cli.fields import Flag, model_options
from qsls.pipeline.export.options import ReplayOptions

EXAMPLE = "qsls replay controllers/l1_robust flight.bag --out replay.mcap"


def _band(text: str, flag: str) -> list[float]:
    """``--thrust-band LOW,HIGH``."""
    from qsls.pipeline.core.errors import ConfigError

    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise ConfigError(f"{flag}: expected LOW,HIGH, got '{text}'") from None


@cli_errors
@model_options(
    ReplayOptions,
    {
        "vio_topic": ("--vio-topic",),
        "reference": ("--reference",),
        "reference_t0": ("--reference-t0",),
        "backend": ("--backend",),
        "max_tilt_deg": ("--max-tilt-deg",),
        "thrust_band": Flag(("--thrust-band",), parse=_band),
        "hover_thrust": ("--hover-thrust",),
        "max_gap": ("--max-gap",),
        "stamp": ("--stamp",),
        "vio_velocity_frame": ("--vio-velocity-frame",),
        "drop_nonfinite": ("--drop-nonfinite",),
        "allow_uncertified": ("--allow-uncertified",),
        "align": ("--align",),
        "vio_to_reference": ("--vio-to-reference",),
        "tilt_limit_deg": ("--tilt-limit-deg",),
        "thrust_limits": ("--thrust-limits",),
        "velocity_window": ("--velocity-window",),
        "command_topic": ("--command-topic",),
        "frame_id": ("--frame-id",),
        "warn_deviation_m": ("--warn-deviation-m",),
    },
)
def command(
    controller: Path = typer.Argument(..., help="Controller folder written by 'qsls synth'."),
    source: Path = typer.Argument(
        ..., help="The recorded VIO: any source 'qsls ingest' reads (bag, MCAP, TUM, EuRoC)."
    ),
    out: Path = typer.Option(..., "--out", "-o", help="Output ROS 2 MCAP file (*.mcap)."),
    config: Path | None = typer.Option(None, "--config", help="YAML file of replay options."),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output file."),
    *,
    given: dict[str, Any],
) -> None:
    """Dry-run the exported controller on a recorded VIO stream; commands to a ROS 2 MCAP."""
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.export.replay import replay

    options = load_options(ReplayOptions, config, given, section="replay")
    result = replay(controller, source, options, out, force=force)
    for g in result.report["gaps"]:
        typer.echo(
            f"warning: VIO gap of {g['duration_s']:.3f} s at {g['t_start_s']:.3f} s: no commands "
            "there, controller reset after it",
            err=True,
        )
    for w in result.report["warnings"]:
        typer.echo(f"WARNING: {w}", err=True)
    print_summary("qsls replay", result.summary())
