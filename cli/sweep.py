"""``qsls sweep``: a grid of robust syntheses, locally or on a Dask cluster."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import cli_errors, parse_list, print_summary
from qsls.cli.fields import Flag, model_options
from qsls.cli.problem import PROBLEM, PROBLEM_CONFIG_ONLY
from qsls.pipeline.control.options import SweepSection


def grid_axis(text: str) -> tuple[str, list]:
    """``"S=0.1,0.2,p95"`` -> ``("S", [0.1, 0.2, "p95"])`` (``T`` values as integers,
    ``true``/``false`` as booleans)."""
    from qsls.pipeline.core.errors import ConfigError

    if "=" not in text:
        raise ConfigError(f"--grid '{text}': expected AXIS=V1,V2,... (e.g. S=0.05,0.1,p95)")
    axis, _, values = text.partition("=")
    axis = axis.strip()
    out = parse_list(values, f"--grid {axis}", "int" if axis == "T" else "value") or []
    return axis.strip(), out


EXAMPLE = "qsls sweep --model fit -g S=p50,p90,max -g T=10,20 --out sweep"


def _grid(values: list[str], flag: str) -> dict[str, list] | None:
    """The ``--grid`` axes given (none given: ``None``, the config's or the model's grid)."""
    return dict(grid_axis(g) for g in values) or None


def _scheduler(address: str, flag: str) -> str:
    from qsls.pipeline.control.sweep import check_scheduler

    return check_scheduler(address)


@cli_errors
@model_options(
    SweepSection,
    {
        "grid": Flag(("--grid", "-g"), parse=_grid, kind=list[str]),
        **PROBLEM,
        "jobs": ("--jobs", "-j"),
        "scheduler": Flag(("--scheduler",), parse=_scheduler),
        "wait_workers": ("--wait-workers",),
        "certify": ("--certify/--no-certify",),
        "s_max_curve": ("--s-max-curve/--no-s-max-curve",),
        "chunks_per_job": ("--chunks-per-job",),
    },
    config_only=PROBLEM_CONFIG_ONLY,
)
def command(
    config: Path | None = typer.Option(
        None,
        "--config",
        "-c",
        help="YAML file: base synth options plus 'grid' (axis: list of values).",
    ),
    out: Path = typer.Option(
        ..., "--out", "-o", help="Output folder (sweep.parquet, sweep.csv, figures)."
    ),
    model: Path | None = typer.Option(
        None,
        "--model",
        "-m",
        help="error_model.yaml or fit folder (needed when S/eps_e are names).",
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
    *,
    given: dict[str, Any],
) -> None:
    """A grid of robust syntheses (feasibility map), locally or on a Dask cluster."""
    from qsls.cli.common import RichProgress
    from qsls.pipeline.control.sweep import SweepSection, sweep
    from qsls.pipeline.core.config import merge, read_section, validate
    from qsls.pipeline.core.errors import ConfigError

    if "jobs" in given and "scheduler" in given:
        raise ConfigError("give --jobs or --scheduler, not both")
    data = read_section(config, "sweep")
    if "jobs" in given or "scheduler" in given:  # the command line's executor replaces the file's
        data = {k: v for k, v in data.items() if k not in ("jobs", "scheduler")}
    section = validate(SweepSection, merge(data, given), str(config or "options"))
    with RichProgress() as progress:
        result = sweep(
            section.options(), out, error_model=model, force=force, progress=progress,
            jobs=section.jobs, scheduler=section.scheduler, worker_timeout=section.wait_workers,
        )  # fmt: skip
    print_summary("sweep", result.summary())
