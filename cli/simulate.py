"""Simulate a quadrotor flight with a VIO emulator and write it as a ROS1/ROS2/MCAP bag."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import RichProgress, cli_errors, print_summary
from qsls.cli.fields import Flag, model_options
from qsls.pipeline.sim.options import SimOptions

EXAMPLE = "qsls simulate --out flights/sim1 --seed 1 --format mcap"


@cli_errors
@model_options(
    SimOptions,
    {
        "seed": ("--seed",),
        "duration": ("--duration",),
        "vio.perception": ("--perception",),
        "vio.kind": Flag(("--vio",), name="vio"),
        "controller.kind": Flag(("--controller",), name="controller"),
        "log.format": Flag(("--format",), name="fmt"),
        "controller.backend": Flag(("--backend",), name="backend"),
        "px4.interface": Flag(("--interface",), name="interface"),
    },
    config_only={
        "vehicle": "mass, drag, thrust_constant, sag",
        "wind": "speed, direction_deg, gust, gust_hz",
        "start_offset": "x and y (m) beside the reference's first point",
        "reference": "kind, radius, height, period, ...",
        "crash": "the crash limits",
        "mocap": "the motion capture's noise and rate",
        "vio, controller, log, px4": "their other fields",
    },
)
def command(
    out: Path = typer.Option(
        ...,
        "--out",
        "-o",
        help="Output folder: the log (flight.bag, flight/, flight.mcap or flight.ulg), truth.json, "
        "errors.parquet, trajectory.parquet, control.parquet, ticks.parquet (the "
        "controller's own log), manifest.json.",
    ),
    config: Path = typer.Option(
        None,
        "--config",
        help="YAML file of options (see configs/simulate.yaml; a 'simulate:' section is "
        "used when present). The command line wins.",
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite --out if it exists."),
    *,
    given: dict[str, Any],
) -> None:
    """Simulate a quadrotor flight with a VIO emulator and write it as a ROS1/ROS2/MCAP bag."""
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.sim.simulate import simulate

    options = load_options(SimOptions, config, given, section="simulate")
    with RichProgress() as progress:
        result = simulate(options, out, force=force, progress=progress)
    if result.flight.crashed:
        typer.echo(
            f"warning: the flight crashed ({result.flight.crash_reason}); "
            "the log ends there and truth.json has crashed: true",
            err=True,
        )
    print_summary("qsls simulate", result.summary())
