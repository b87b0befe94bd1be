"""Fly the controllers side by side in simulation: every assumption checked, the paper's findings."""

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
    print_table,
    print_verdicts,
)
from qsls.pipeline.evaluate.options import FlyOptions
from qsls.pipeline.sim.options import ControllerOptions

EXAMPLE = "qsls fly --model fit --controller synth --out fly --seeds 0,1,2"


@cli_errors
def command(
    model: Path = typer.Option(
        ...,
        "--model",
        help="Error model: error_model.yaml or the 'qsls fit' folder holding it.",
    ),
    controller: list[Path] = typer.Option(
        ...,
        "--controller",
        help="Controller folder written by 'qsls synth' or 'qsls calibrate' (holds "
        "certificate.yaml), or a synth output folder for all its controllers. Repeatable.",
    ),
    out: Path = typer.Option(
        ...,
        "--out",
        help="Output folder (the flights, findings.json, comparison.md, figures).",
    ),
    config: Path = typer.Option(
        None,
        "--config",
        help="YAML file of options: its 'evaluate:' section and the 'fly:' under it, as in "
        "a run config (the command line wins).",
    ),
    seeds: str = model_option(
        FlyOptions, "seeds", "--seeds",
        help="Comma-separated seeds, one flight per seed, controller and condition.",
    ),
    duration: float = model_option(
        FlyOptions, "duration", "--duration",
        help="Seconds per flight.",
    ),
    conditions: str = model_option(
        FlyOptions, "conditions", "--conditions",
        help="Comma-separated perception conditions.",
    ),
    jobs: int = model_option(FlyOptions, "jobs", "--jobs", help="Parallel flights, 0 = all cores."),
    scheduler: str = model_option(
        FlyOptions, "scheduler", "--scheduler", none="the local pool",
        help="Dask scheduler address (tcp://host:8786): the flights run on its workers, with "
        "the same tables as the local pool.",
    ),
    wait_workers: float = model_option(
        FlyOptions, "wait_workers", "--wait-workers",
        help="With --scheduler: seconds to wait for a first worker, and for one to come back "
        "after every worker left, before failing.",
    ),
    vio: str = model_option(
        FlyOptions, "vio", "--vio",
        help="Where the estimate comes from: 'emulator' (the VIO error model) or 'camera' (rendered "
        "camera, IMU and MSCKF); 'camera,emulator' flies both, paired by seed.",
    ),
    backend: str = model_option(
        ControllerOptions, "backend", "--backend",
        help="python or c: fly the synthesized controllers as the C of 'qsls export' (compiled, "
        "through ctypes).",
    ),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the PNG figures."),
    force: bool = typer.Option(
        False, "--force", help="Overwrite --out; another error model's controller only warns."
    ),
) -> None:
    """Fly the controllers side by side in simulation: every assumption checked, the paper's findings."""
    fly(
        model, controller, out, config, force,
        overrides(
            figures=False if no_figures else None,
            seeds=parse_list(seeds, "--seeds", "int"), duration=duration, jobs=jobs,
            scheduler=scheduler, wait_workers=wait_workers,
            conditions=parse_list(conditions, "--conditions", "value"),
            vio=parse_list(vio, "--vio", "value") if vio and "," in vio else vio,
            sim={"controller": {"backend": backend}} if backend else None,
        ),
    )  # fmt: skip


def fly(
    model: Path,
    controllers: list[Path],
    out: Path,
    config: Path | None,
    force: bool,
    given: dict[str, object],
    title: str = "qsls fly",
) -> None:
    """Fly (the options: the config's ``evaluate:`` section, its ``fly:``, then ``given``),
    then the summary, the paper comparison and the verdicts."""
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.evaluate.fly import fly_evaluate
    from qsls.pipeline.evaluate.section import EvaluateSection
    from qsls.pipeline.evaluate.verdict import combined

    section = load_options(EvaluateSection, config, None, section="evaluate")
    options = section.flying(given, str(config or "options"))
    with RichProgress() as progress:
        result = fly_evaluate(model, controllers, options, out, force=force, progress=progress)
    print_summary(title, result.summary())
    cols, rows = result.comparison_rows()
    print_table("Against the paper's findings", cols, rows)
    print_verdicts("Certified bound on the flown flights", combined(result.table, result.assumptions))
