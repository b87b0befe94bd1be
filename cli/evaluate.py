"""Check certified bounds on held-out flights (``qsls fly`` flies the controllers; ``--fly`` is its
old alias)."""

from __future__ import annotations

from pathlib import Path

import typer

from qsls.cli.common import (
    RichProgress,
    cli_errors,
    model_option,
    overrides,
    parse_list,
    print_summary,
    print_verdicts,
)
from qsls.pipeline.evaluate.options import FlyOptions
from qsls.pipeline.sim.options import ControllerOptions

EXAMPLE = "qsls evaluate --model fit --controller synth --flights flights/f3 --out ev"


@cli_errors
def command(
    model: Path = typer.Option(
        ...,
        "--model",
        help="Error model: error_model.yaml or the 'qsls fit' folder holding it "
        "(its training_states.parquet gives the distance to the training data).",
    ),
    controller: list[Path] = typer.Option(
        ...,
        "--controller",
        help="Controller folder written by 'qsls synth' (holds "
        "certificate.yaml), or a synth output folder for all its controllers. Repeatable.",
    ),
    flights: list[Path] = typer.Option(
        None,
        "--flights",
        help="Held-out flight folder written by 'qsls ingest'. Repeatable.",
    ),
    out: Path = typer.Option(
        ..., "--out", help="Output folder (evaluation.json, .parquet, figures)."
    ),
    fly: bool = typer.Option(
        False,
        "--fly",
        hidden=True,
        help="The old spelling of 'qsls fly' (says so on stderr): fly the controllers "
        "instead of checking --flights.",
    ),
    config: Path = typer.Option(
        None, "--config", help="YAML file of options (the command line wins)."
    ),
    smooth_s: float = model_option(
        FlyOptions, "smooth_s", "--smooth-s",
        help="Time constant (s) of the average drawn over ||e|| in the figures (0: none).",
    ),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the PNG figures."),
    flown_by: str = model_option(
        FlyOptions, "flown_by", "--flown-by", none="none: recorded flights, premise only",
        help="Name of the --controller that flew the --flights: the theorem is checked on its flights; "
        "every other pair checks the premise only.",
    ),
    seeds: str = model_option(
        FlyOptions, "seeds", "--seeds", hidden=True,
        help="With --fly (qsls fly): comma-separated seeds.",
    ),
    duration: float = model_option(
        FlyOptions, "duration", "--duration", hidden=True,
        help="With --fly (qsls fly): seconds per flight.",
    ),
    conditions: str = model_option(
        FlyOptions, "conditions", "--conditions", hidden=True,
        help="With --fly (qsls fly): comma-separated perception conditions.",
    ),
    jobs: int = model_option(
        FlyOptions, "jobs", "--jobs", hidden=True,
        help="With --fly (qsls fly): parallel flights, 0 = all cores.",
    ),
    scheduler: str = model_option(
        FlyOptions, "scheduler", "--scheduler", hidden=True, none="the local pool",
        help="With --fly (qsls fly): Dask scheduler address (tcp://host:8786); the flights run on "
        "its workers, with the same tables as the local pool.",
    ),
    vio: str = model_option(
        FlyOptions, "vio", "--vio", hidden=True,
        help="With --fly (qsls fly): where the estimate comes from: 'emulator' (the VIO error model) "
        "or 'camera' (rendered camera, IMU and MSCKF); 'camera,emulator' flies both, paired by "
        "seed.",
    ),
    backend: str = model_option(
        ControllerOptions, "backend", "--backend", hidden=True,
        help="With --fly (qsls fly): python or c: fly the synthesized controllers as the C of 'qsls "
        "export' (compiled, through ctypes).",
    ),
    force: bool = typer.Option(
        False, "--force", help="Overwrite --out; another error model's controller only warns."
    ),
) -> None:
    """Check the certified bounds on held-out flights (to fly the controllers: qsls fly)."""
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.core.errors import InputError
    from qsls.pipeline.evaluate.section import EvaluateSection
    from qsls.pipeline.evaluate.verdict import combined

    ov = overrides(smooth_s=smooth_s, figures=False if no_figures else None, flown_by=flown_by)
    if fly:
        from qsls.cli.fly import fly as fly_command

        typer.echo("warning: 'qsls evaluate --fly' is the old spelling of 'qsls fly'; "
                   "it runs 'qsls fly' and will go", err=True)  # fmt: skip
        if flights:
            raise InputError("--flights is not used with --fly (the flights are flown); drop one")
        if flown_by:
            raise InputError("--flown-by is not used with --fly (each flight records its own)")
        given = overrides(
            smooth_s=smooth_s, figures=False if no_figures else None,
            seeds=parse_list(seeds, "--seeds", "int"), duration=duration, jobs=jobs,
            scheduler=scheduler,
            conditions=parse_list(conditions, "--conditions", "value"),
            vio=parse_list(vio, "--vio", "value") if vio and "," in vio else vio,
            sim={"controller": {"backend": backend}} if backend else None,
        )  # fmt: skip
        fly_command(model, controller, out, config, force, given, "qsls evaluate --fly")
        return
    section = load_options(EvaluateSection, config, ov, section="evaluate")
    from qsls.pipeline.evaluate.bound import evaluate

    with RichProgress() as progress:
        checked = evaluate(
            flights or [], model, controller, section.bound(), out, force=force, progress=progress
        )
    for w in checked.warnings:
        typer.echo(f"warning: {w}", err=True)
    print_summary("qsls evaluate", checked.summary())
    print_verdicts("Certified bound on the held-out flights", combined(checked.table, checked.assumptions))
