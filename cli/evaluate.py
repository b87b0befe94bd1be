"""Check certified bounds on held-out flights, or fly the controllers side by side (--fly)."""

from __future__ import annotations

from pathlib import Path

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
        help="Time constant (s) of the average drawn over ||e|| in figures (0: none). (default: 1)",
    ),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the PNG figures."),
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
    backend: str = typer.Option(
        None,
        "--backend",
        help="--fly: python or c: fly the synthesized controllers as the C of "
        "'qsls export' (compiled, through ctypes). (default: python)",
    ),
    force: bool = typer.Option(
        False,
        "--force",
        help="Overwrite --out, and check a controller certified against a "
        "different error model anyway (with a warning).",
    ),
) -> None:
    """Check certified bounds on held-out flights, or fly the controllers side by side (--fly)."""
    from qsls.pipeline.core.config import merge, read_section, validate
    from qsls.pipeline.core.errors import InputError
    from qsls.pipeline.evaluate.verdict import verdicts

    # The config's 'evaluate' section (or the whole file), read as every command reads its
    # section; its 'fly' mapping (as in a 'qsls run' config) adds the flying options.
    section = read_section(config, "evaluate")
    fly_cfg = section.pop("fly", None)
    ov = overrides(smooth_s=smooth_s, figures=False if no_figures else None)
    if fly:
        from qsls.pipeline.evaluate.fly import FlyOptions, fly_evaluate

        if flights:
            raise InputError("--flights is not used with --fly (the flights are flown); drop one")
        seed_list = parse_list(seeds, "--seeds", "int") or None
        ov.update(
            overrides(
                seeds=seed_list,
                duration=duration,
                conditions=[c.strip() for c in conditions.split(",") if c.strip()]
                if conditions
                else None,
                jobs=jobs,
                sim={"controller": {"backend": backend}} if backend else None,
            )
        )
        base = merge(section, fly_cfg) if isinstance(fly_cfg, dict) else section
        options = validate(FlyOptions, merge(base, ov), str(config or "options"))
        with RichProgress() as progress:
            result = fly_evaluate(model, controller, options, out, force=force, progress=progress)
        print_summary("qsls evaluate --fly", result.summary())
        cols, rows = result.comparison_rows()
        print_table("Against the paper's findings", cols, rows)
        print_verdicts("Certified bound on the flown flights", verdicts(result.table))
        return
    from qsls.pipeline.evaluate.bound import EvaluateOptions, evaluate

    bound_options = validate(EvaluateOptions, merge(section, ov), str(config or "options"))
    with RichProgress() as progress:
        checked = evaluate(
            flights or [], model, controller, bound_options, out, force=force, progress=progress
        )
    for w in checked.warnings:
        typer.echo(f"warning: {w}", err=True)
    print_summary("qsls evaluate", checked.summary())
    print_verdicts("Certified bound on the held-out flights", verdicts(checked.table))
