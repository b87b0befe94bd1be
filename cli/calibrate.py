"""``qsls calibrate``: a certificate calibrated on the candidate's own flights (docs/calibration.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import cli_errors
from qsls.cli.fields import Flag, model_options, repeated_list
from qsls.pipeline.calibrate.options import CalibrateOptions


def count_or_flights(texts: list[str], flag: str) -> int | list[str]:
    """``--flights N`` (simulated flights per candidate) or ``--flights F1 [F2 ...]`` (recorded
    calibration flights: ingest folders, as ``--recorded``)."""
    items = repeated_list(texts, flag)
    if len(items) == 1 and items[0].lstrip("+").isdigit():
        return int(items[0])
    return items


EXAMPLE = (
    "qsls calibrate -m fit --controllers synth -o cal --range-flights 20 --tube 2\n"
    "  (20 calibration flights: certified needs 19; range flights over a 2 m tube\n"
    "  reach rho*: without them the certificate says extrapolated)\n"
    "  qsls calibrate -m fit --controllers synth -o cal --recorded flights/cal \\\n"
    "      --recorded-range flights/range --recorded-validation flights/val"
)


@cli_errors
@model_options(
    CalibrateOptions,
    {
        "flights": Flag(("--flights",), parse=count_or_flights, kind=list[str]),
        "validation": ("--validation",),
        "range_flights": ("--range-flights",),
        "tube": ("--tube",),
        "alpha": ("--alpha",),
        "method": ("--method",),
        "delta": ("--delta",),
        "seed": ("--seed",),
        "validation_seed": ("--validation-seed",),
        "range_seed": ("--range-seed",),
        "design_seeds": ("--design-seeds",),
        "conditions": ("--conditions",),
        "controllers": Flag(("--only",), name="only"),
        "duration": ("--duration",),
        "jobs": ("--jobs", "-j"),
        "scheduler": ("--scheduler",),
        "wait_workers": ("--wait-workers",),
        "recorded.calibration": Flag(
            ("--recorded",), name="recorded", parse=repeated_list, kind=list[str]
        ),
        "recorded.range": Flag(
            ("--recorded-range",), name="recorded_range", parse=repeated_list, kind=list[str]
        ),
        "recorded.validation": Flag(
            ("--recorded-validation",),
            name="recorded_validation",
            parse=repeated_list,
            kind=list[str],
        ),
        "source": ("--source",),
        "standin_log": ("--standin-log",),
        "monitor.mode": ("--monitor",),
        "monitor.false_trip_rate": ("--false-trip-rate",),
    },
    config_only={
        "sim": "the vehicle, reference and VIO: a run config's simulate: section",
        "family": "the conditions the flights draw from, a mapping",
    },
)
def command(
    model: Path = typer.Option(
        ..., "--model", "-m", help="error_model.yaml or the fit folder holding it (qsls fit)."
    ),
    controllers: Path = typer.Option(
        ..., "--controllers", help="The synth folder (qsls synth) holding the candidates."
    ),
    out: Path = typer.Option(
        ...,
        "--out",
        "-o",
        help="Output folder: <condition>/<controller>/ (the calibrated certificates), the "
        "scores, the validation and each flight's tick log.",
    ),
    config: Path = typer.Option(
        None,
        "--config",
        "-c",
        help="YAML file of these options (its 'calibrate' section, or all; 'sim' holds the "
        "vehicle, reference and estimator the flights fly).",
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
    more: list[str] = typer.Argument(
        None, hidden=True, help="More recorded calibration flights after --flights F1 (F2 ...)."
    ),
    *,
    given: dict[str, Any],
) -> None:
    """Calibrate the candidates' premise on flights they fly themselves, then validate it."""
    if more:  # qsls calibrate --flights F1 F2 F3: the folders after the first
        if not isinstance(given.get("flights"), list):
            raise typer.BadParameter(f"unexpected argument {more[0]!r}", param_hint="FLIGHTS")
        given = {**given, "flights": [*given["flights"], *more]}
    from qsls.cli.common import RichProgress, print_summary, print_verdicts
    from qsls.pipeline.calibrate.stage import calibrate
    from qsls.pipeline.calibrate.summary import simulated_notice, summary_lines
    from qsls.pipeline.core.config import load_options

    options = load_options(CalibrateOptions, config, given, section="calibrate")
    if not options.flies_recorded:
        options.seed_lists()
        typer.echo(simulated_notice(options))
    with RichProgress() as progress:
        result = calibrate(model, controllers, options, out, force=force, progress=progress)
    print_summary("qsls calibrate", result.summary())
    print_verdicts("Calibrated certificates", summary_lines(out))
