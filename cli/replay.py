"""``qsls replay``: a recorded VIO stream through the exported controller, commands to an MCAP."""

from __future__ import annotations

from pathlib import Path

import typer

from qsls.cli.common import cli_errors, model_option, overrides, parse_list, print_summary
from qsls.pipeline.export.options import ReplayOptions

EXAMPLE = "qsls replay controllers/l1_robust flight.bag --out replay.mcap"


@cli_errors
def command(
    controller: Path = typer.Argument(..., help="Controller folder written by 'qsls synth'."),
    source: Path = typer.Argument(
        ..., help="The recorded VIO: any source 'qsls ingest' reads (bag, MCAP, TUM, EuRoC)."
    ),
    out: Path = typer.Option(..., "--out", "-o", help="Output ROS 2 MCAP file (*.mcap)."),
    vio_topic: str | None = model_option(
        ReplayOptions, "vio_topic", "--vio-topic", none="the only nav_msgs/Odometry topic",
        help="VIO topic.",
    ),
    reference: str | None = model_option(
        ReplayOptions, "reference", "--reference",
        help="Reference as KIND[:key=value,...] (circle, hover, figure8 with the simulator's "
        "options, e.g. circle:radius=1,period=5,height=1) or a YAML file.",
    ),
    reference_t0: float | None = model_option(
        ReplayOptions, "reference_t0", "--reference-t0",
        help="Reference time (s) at the first tick.",
    ),
    backend: str | None = model_option(
        ReplayOptions, "backend", "--backend",
        help="Exported code that runs: python or c (compiled).",
    ),
    max_tilt_deg: float | None = model_option(
        ReplayOptions, "max_tilt_deg", "--max-tilt-deg", help="Tilt limit for the report (deg)."
    ),
    thrust_band: str | None = model_option(
        ReplayOptions, "thrust_band", "--thrust-band",
        help="LOW,HIGH thrust band in multiples of hover.",
    ),
    hover_thrust: float | None = model_option(
        ReplayOptions, "hover_thrust", "--hover-thrust",
        help="Normalized thrust at hover for AttitudeTarget.",
    ),
    max_gap: float | None = model_option(
        ReplayOptions, "max_gap", "--max-gap",
        help="Never interpolate across a gap longer than this (s).",
    ),
    stamp: str | None = model_option(
        ReplayOptions, "stamp", "--stamp", help="Time of a message: header stamp or bag log time."
    ),
    vio_velocity_frame: str | None = model_option(
        ReplayOptions, "vio_velocity_frame", "--vio-velocity-frame",
        help="Frame of the Odometry twist: body or world.",
    ),
    drop_nonfinite: bool = model_option(
        ReplayOptions, "drop_nonfinite", "--drop-nonfinite",
        help="Skip messages with NaN/inf values instead of stopping.",
    ),
    allow_uncertified: bool = model_option(
        ReplayOptions, "allow_uncertified", "--allow-uncertified",
        help="Replay a controller whose status is not 'certified'.",
    ),
    align: str | None = model_option(
        ReplayOptions, "align", "--align",
        help="Put the VIO into the reference's frame: 4dof (fit yaw + offset) or none.",
    ),
    vio_to_reference: str | None = model_option(
        ReplayOptions, "vio_to_reference", "--vio-to-reference", none="none: --align",
        help="A known transform instead of the fit: X,Y,Z,YAW_DEG (p_ref = Rz(yaw) p_vio + xyz).",
    ),
    tilt_limit_deg: float | None = model_option(
        ReplayOptions, "tilt_limit_deg", "--tilt-limit-deg",
        help="The exported helper's tilt limit (deg).",
    ),
    thrust_limits: str | None = model_option(
        ReplayOptions, "thrust_limits", "--thrust-limits",
        help="The exported helper's LOW,HIGH thrust x hover.",
    ),
    config: Path | None = typer.Option(None, "--config", help="YAML file of replay options."),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output file."),
) -> None:
    """Dry-run the exported controller on a recorded VIO stream; commands to a ROS 2 MCAP."""
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.core.errors import ConfigError
    from qsls.pipeline.export.replay import replay

    band = None
    if thrust_band is not None:
        try:
            band = [float(v) for v in thrust_band.split(",")]
        except ValueError:
            raise ConfigError(f"--thrust-band: expected LOW,HIGH, got '{thrust_band}'") from None
    given = overrides(
        vio_topic=vio_topic,
        reference=reference,
        reference_t0=reference_t0,
        backend=backend,
        max_tilt_deg=max_tilt_deg,
        thrust_band=band,
        hover_thrust=hover_thrust,
        max_gap=max_gap,
        stamp=stamp,
        vio_velocity_frame=vio_velocity_frame,
        drop_nonfinite=drop_nonfinite or None,
        allow_uncertified=allow_uncertified or None,
        align=align,
        vio_to_reference=parse_list(vio_to_reference, "--vio-to-reference"),
        tilt_limit_deg=tilt_limit_deg,
        thrust_limits=parse_list(thrust_limits, "--thrust-limits"),
    )
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
