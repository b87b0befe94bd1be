"""Check certified bounds on held-out flights, or fly the controllers side by side (--fly)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import (
    RichProgress,
    cli_errors,
    overrides,
    parse_list,
    print_summary,
    print_table,
    print_verdicts,
)

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
        help="Held-out flight folder written by 'qsls ingest'. Repeatable. "
        "Not used with --fly (the flights are flown).",
    ),
    out: Path = typer.Option(
        ..., "--out", help="Output folder (evaluation.json, .parquet, figures)."
    ),
    fly: bool = typer.Option(
        False,
        "--fly",
        help="Fly every controller plus SE3 on the simulator with the VIO "
        "emulator in the loop, ingest each flight, check bounds and compare with the paper.",
    ),
    config: Path = typer.Option(
        None, "--config", help="YAML file of options (the command line wins)."
    ),
    smooth_s: float = typer.Option(
        None,
        "--smooth-s",
        help="Time constant (s) of the average drawn over ||e|| in the bound check's figures, not --fly's (0: none). (default: 1)",
    ),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the PNG figures."),
    flown_by: str = typer.Option(
        None,
        "--flown-by",
        help="Name of the --controller that flew the --flights: the theorem is checked "
        "on its flights; every other pair checks the premise only. (default: none: "
        "recorded flights, premise only)",
    ),
    seeds: str = typer.Option(
        None, "--seeds", help="--fly: comma-separated seeds. (default: 0,1,2)"
    ),
    duration: float = typer.Option(
        None, "--duration", help="--fly: seconds per flight. (default: 30)"
    ),
    conditions: str = typer.Option(
        None,
        "--conditions",
        help="--fly: comma-separated perception conditions. (default: regular,degraded)",
    ),
    jobs: int = typer.Option(
        None, "--jobs", help="--fly: parallel flights, 0 = all cores. (default: 0)"
    ),
    scheduler: str = typer.Option(
        None, "--scheduler",
        help="--fly: Dask scheduler address (tcp://host:8786); the flights run on its workers, "
        "with the same tables as the local pool. (default: the local pool)",
    ),
    vio: str = typer.Option(
        None,
        "--vio",
        help="--fly: where the estimate comes from: 'emulator' (the VIO error model) or "
        "'camera' (rendered camera, IMU and MSCKF); 'camera,emulator' flies both, paired "
        "by seed. (default: emulator)",
    ),
    backend: str = typer.Option(
        None,
        "--backend",
        help="--fly: python or c: fly the synthesized controllers as the C of "
        "'qsls export' (compiled, through ctypes). (default: python)",
    ),
    assured: bool | None = typer.Option(
        None,
        "--assured/--not-assured",
        help="--fly: also fly each monitored controller runtime-assured: it flies until its "
        "onboard monitor trips, then --fallback flies (docs/monitor.md). "
        "(default: --not-assured)",
    ),
    fallback: str | None = typer.Option(
        None,
        "--fallback",
        help="--fly --assured: 'pd' (PD on the reference) or 'hold' (PD holding the "
        "estimated position of the trip tick). (default: pd)",
    ),
    force: bool = typer.Option(
        False, "--force", help="Overwrite --out; another error model's controller only warns."
    ),
) -> None:
    """Check certified bounds on held-out flights, or fly the controllers side by side (--fly)."""
    import qsls.pipeline.export.cbuild  # noqa: F401  (registers the 'c' controller runtime)
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.core.errors import InputError
    from qsls.pipeline.evaluate.section import EvaluateSection
    from qsls.pipeline.evaluate.verdict import combined

    ov = overrides(smooth_s=smooth_s, figures=False if no_figures else None, flown_by=flown_by)
    if fly and flights:
        raise InputError("--flights is not used with --fly (the flights are flown); drop one")
    if not fly and (assured is not None or fallback):
        raise InputError("--assured and --fallback fly the controllers: add --fly")
    if fly and flown_by:
        raise InputError("--flown-by is not used with --fly (each flight records its own)")
    section = load_options(EvaluateSection, config, ov, section="evaluate")
    source = str(config or "options")
    if fly:
        fly_given = overrides(
            seeds=parse_list(seeds, "--seeds", "int"), duration=duration, jobs=jobs,
            scheduler=scheduler,
            conditions=parse_list(conditions, "--conditions", "value"),
            vio=parse_list(vio, "--vio", "value") if vio and "," in vio else vio,
            sim={"controller": {"backend": backend}} if backend else None,
            assured=assured, fallback=fallback,
        )  # fmt: skip
        _fly(model, controller, out, section.flying({**ov, **fly_given}, source), force)
        return
    from qsls.pipeline.evaluate.bound import evaluate

    with RichProgress() as progress:
        checked = evaluate(
            flights or [], model, controller, section.bound(), out, force=force, progress=progress
        )
    for w in checked.warnings:
        typer.echo(f"warning: {w}", err=True)
    print_summary("qsls evaluate", checked.summary())
    print_verdicts("Certified bound on the held-out flights", combined(checked.table, checked.assumptions))


def _fly(model: Path, controllers: list[Path], out: Path, options: Any, force: bool) -> None:
    """``evaluate --fly``: fly, then the summary, the paper comparison and the verdicts."""
    from qsls.pipeline.evaluate.fly import fly_evaluate
    from qsls.pipeline.evaluate.verdict import combined

    with RichProgress() as progress:
        result = fly_evaluate(model, controllers, options, out, force=force, progress=progress)
    print_summary("qsls evaluate --fly", result.summary())
    cols, rows = result.comparison_rows()
    print_table("Against the paper's findings", cols, rows)
    print_verdicts("Certified bound on the flown flights", combined(result.table, result.assumptions))
