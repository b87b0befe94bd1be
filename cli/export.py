"""``qsls export``: a certified controller as C99 (header + source) or a stdlib Python module."""

from __future__ import annotations

from pathlib import Path

import typer

from qsls.cli.common import cli_errors, model_option, overrides, parse_list, print_summary
from qsls.pipeline.export.options import ExportOptions

EXAMPLE = "qsls export controllers/l1_robust --target c --out export"


@cli_errors
def command(
    controller: Path = typer.Argument(
        ..., help="Controller folder written by 'qsls synth' (controller.npz + certificate.yaml)."
    ),
    target: str | None = model_option(
        ExportOptions, "target", "--target", "-t",
        help="c or python.",
    ),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder for the generated files."),
    precision: str | None = model_option(
        ExportOptions, "precision", "--precision",
        help="C only: double or float (single-precision FPU).",
    ),
    prefix: str | None = model_option(
        ExportOptions, "prefix", "--prefix",
        help="C names and file names.",
    ),
    allow_uncertified: bool = model_option(
        ExportOptions, "allow_uncertified", "--allow-uncertified",
        help="Export a controller whose status is not 'certified'.",
    ),
    verify_ticks: int | None = model_option(
        ExportOptions, "verify_ticks", "--verify-ticks",
        help="Random ticks of the check against the Python realization.",
    ),
    tilt_limit_deg: float | None = model_option(
        ExportOptions, "tilt_limit_deg", "--tilt-limit-deg",
        help="Largest tilt the attitude helper commands (deg).",
    ),
    thrust_limits: str | None = model_option(
        ExportOptions, "thrust_limits", "--thrust-limits",
        help="LOW,HIGH thrust the attitude helper commands, x hover m g.",
    ),
    config: Path | None = typer.Option(None, "--config", help="YAML file of export options."),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
) -> None:
    """Export a certified controller as C99 or a stdlib Python module, checked against Python."""
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.export.stage import export

    given = overrides(
        target=target,
        precision=precision,
        prefix=prefix,
        allow_uncertified=allow_uncertified or None,
        verify_ticks=verify_ticks,
        tilt_limit_deg=tilt_limit_deg,
        thrust_limits=parse_list(thrust_limits, "--thrust-limits"),
    )
    options = load_options(ExportOptions, config, given, section="export")
    result = export(controller, options, out, force=force)
    print_summary("qsls export", result.summary())
