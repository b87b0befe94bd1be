"""``qsls calibrate``: a certificate calibrated on the candidate's own flights (docs/calibration.md)."""

from __future__ import annotations

from pathlib import Path

import typer

from qsls.cli.common import cli_errors, model_option, overrides, parse_list
from qsls.pipeline.evaluate.options import CalibrateOptions

EXAMPLE = "qsls calibrate --model fit --controllers synth --out calibrate --flights 20"


@cli_errors
def command(
    model: Path = typer.Option(
        ..., "--model", "-m", help="error_model.yaml or the fit folder holding it (qsls fit)."
    ),
    controllers: Path = typer.Option(
        ..., "--controllers", help="The synth folder (qsls synth) holding the candidates."
    ),
    out: Path = typer.Option(
        ..., "--out", "-o",
        help="Output folder: <condition>/<controller>/ (the calibrated certificates), the "
        "scores, the validation and each flight's tick log.",
    ),
    flights: int = model_option(
        CalibrateOptions, "flights", "--flights",
        help="Calibration flights per candidate and condition.",
    ),
    validation: int = model_option(
        CalibrateOptions, "validation", "--validation",
        help="Fresh validation flights per candidate.",
    ),
    range_flights: int = model_option(
        CalibrateOptions, "range_flights", "--range-flights",
        help="Flights over a tube of references (the perception premise out to rho*).",
    ),
    tube: float = model_option(
        CalibrateOptions, "tube", "--tube",
        help="Radius (m) of the range flights' reference offsets.",
    ),
    alpha: float = model_option(
        CalibrateOptions, "alpha", "--alpha",
        help="The stated probability that a new flight breaks the premise.",
    ),
    method: str = model_option(
        CalibrateOptions, "method", "--method",
        help="conformal (marginal) or pac (with --delta).",
    ),
    delta: float = model_option(
        CalibrateOptions, "delta", "--delta",
        help="1 - confidence of the pac statement.",
    ),
    seed: int = model_option(CalibrateOptions, "seed", "--seed", help="First calibration seed."),
    validation_seed: int = model_option(
        CalibrateOptions, "validation_seed", "--validation-seed",
        help="First validation seed.",
    ),
    range_seed: int = model_option(
        CalibrateOptions, "range_seed", "--range-seed",
        help="First range-flight seed.",
    ),
    design_seeds: str = model_option(
        CalibrateOptions, "design_seeds", "--design-seeds",
        help="Comma-separated seeds of the design flights: refused as calibration or validation seeds.",
    ),
    conditions: str = model_option(
        CalibrateOptions, "conditions", "--conditions",
        help="Comma-separated perception conditions, one certificate each.",
    ),
    only: str = model_option(
        CalibrateOptions, "controllers", "--only", none="every robust one",
        help="Comma-separated candidate names.",
    ),
    duration: float = model_option(
        CalibrateOptions, "duration", "--duration",
        help="Seconds per flight.",
    ),
    jobs: int = model_option(
        CalibrateOptions, "jobs", "--jobs", "-j",
        help="Flights in parallel; 0 = all cores.",
    ),
    scheduler: str = model_option(
        CalibrateOptions, "scheduler", "--scheduler", none="the local pool",
        help="Dask scheduler address (tcp://host:8786): the flights run on its workers, with the same "
        "tables as the local pool.",
    ),
    wait_workers: float = model_option(
        CalibrateOptions, "wait_workers", "--wait-workers",
        help="With --scheduler: seconds to wait for a worker before failing.",
    ),
    config: Path = typer.Option(
        None, "--config", "-c",
        help="YAML file of these options (its 'calibrate' section, or all; 'sim' holds the "
        "vehicle, reference and estimator the flights fly).",
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
) -> None:
    """Calibrate the candidates' premise on flights they fly themselves, then validate it."""
    from qsls.cli.common import RichProgress, print_summary, print_verdicts
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.evaluate.calibrate import calibrate, summary_lines
    from qsls.pipeline.evaluate.options import CalibrateOptions

    given = overrides(
        flights=flights, validation=validation, range_flights=range_flights, tube=tube,
        alpha=alpha, method=method, delta=delta, seed=seed, validation_seed=validation_seed,
        range_seed=range_seed, design_seeds=parse_list(design_seeds, "--design-seeds", "int"),
        conditions=parse_list(conditions, "--conditions", "value"),
        controllers=parse_list(only, "--only", "value"), duration=duration, jobs=jobs,
        scheduler=scheduler, wait_workers=wait_workers,
    )  # fmt: skip
    options = load_options(CalibrateOptions, config, given, section="calibrate")
    options.seed_lists()
    with RichProgress() as progress:
        result = calibrate(model, controllers, options, out, force=force, progress=progress)
    print_summary("qsls calibrate", result.summary())
    print_verdicts("Calibrated certificates", summary_lines(out))
