"""Simulate a quadrotor flight with a VIO emulator and write it as a ROS1/ROS2/MCAP bag."""

from __future__ import annotations

from pathlib import Path

import typer

from qsls.cli.common import RichProgress, cli_errors, model_option, overrides, print_summary
from qsls.pipeline.sim.options import ControllerOptions, LogOptions, SimOptions, VioParams

EXAMPLE = "qsls simulate --out flights/sim1 --seed 1 --format mcap"


@cli_errors
def command(
    out: Path = typer.Option(
        ...,
        "--out",
        "-o",
        help="Output folder: the bag (flight.bag, flight/ or flight.mcap), truth.json, "
        "errors.parquet, trajectory.parquet, control.parquet, manifest.json.",
    ),
    config: Path = typer.Option(
        None,
        "--config",
        help="YAML file of options (see configs/simulate.yaml; a 'simulate:' section is "
        "used when present). The command line wins.",
    ),
    seed: int = model_option(
        SimOptions, "seed", "--seed",
        help="Random seed of the VIO emulator and logs.",
    ),
    duration: float = model_option(
        SimOptions, "duration", "--duration",
        none="take-off, approach and the reference's laps: 23 s for 3 laps of the 5 s circle",
        help="Flight length in seconds.",
    ),
    perception: str = model_option(
        VioParams, "perception", "--perception",
        help="VIO conditions: 'regular' or 'degraded' (less light and texture).",
    ),
    vio: str = model_option(
        VioParams, "kind", "--vio",
        help="Where the estimate comes from: 'emulator' (the VIO error model) or 'camera' (a rendered "
        "camera, an IMU and an MSCKF; vio.camera in the config).",
    ),
    controller: str = model_option(
        ControllerOptions, "kind", "--controller",
        help="'se3' (RotorPy's SE3), 'pd', or a controller folder from 'qsls synth'.",
    ),
    fmt: str = model_option(
        LogOptions, "format", "--format",
        help="Bag format: ros1, ros2-sqlite, ros2-mcap or mcap.",
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite --out if it exists."),
) -> None:
    """Simulate a quadrotor flight with a VIO emulator and write it as a ROS1/ROS2/MCAP bag."""
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.sim.simulate import SimOptions, simulate

    ov = overrides(
        seed=seed,
        duration=duration,
        vio=overrides(perception=perception, kind=vio) or None,
        controller=overrides(kind=controller) or None,
        log=overrides(format=fmt) or None,
    )
    options = load_options(SimOptions, config, ov, section="simulate")
    with RichProgress() as progress:
        result = simulate(options, out, force=force, progress=progress)
    if result.flight.crashed:
        typer.echo(
            f"warning: the flight crashed ({result.flight.crash_reason}); "
            "the log ends there and truth.json has crashed: true",
            err=True,
        )
    print_summary("qsls simulate", result.summary())
