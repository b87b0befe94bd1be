"""``qsls sweep``: a grid of robust syntheses, locally or on a Dask cluster."""

from __future__ import annotations

from pathlib import Path

import typer

from qsls.cli.common import (
    cli_errors,
    model_option,
    number_or_name,
    overrides,
    parse_list,
    print_summary,
)
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


@cli_errors
def command(
    config: Path | None = typer.Option(
        None,
        "--config",
        "-c",
        help="YAML file: base synth options plus 'grid' (axis: list of values).",
    ),
    grid: list[str] | None = model_option(
        SweepSection, "grid", "--grid", "-g",
        help="A grid axis, AXIS=V1,V2,.. (repeatable; replaces that axis of the config).",
    ),
    horizon: int | None = model_option(
        SweepSection, "T", "--T", "-T",
        help="Base horizon T (when T is not a grid axis).",
    ),
    norm: str | None = model_option(SweepSection, "norm", "--norm", help="Base norm: l1 or h2."),
    cost: str | None = model_option(
        SweepSection, "cost", "--cost",
        help="Base cost: qr or imitation.",
    ),
    s: str | None = model_option(
        SweepSection, "S", "--S",
        help="Base S: a number, lofo (leave-one-flight-out) or an error-model name.",
    ),
    eps_e: str | None = model_option(
        SweepSection, "eps_e", "--eps-e",
        help="Base eps_e: a number or a name.",
    ),
    radius: float | None = model_option(
        SweepSection, "radius", "--radius", "-r", none="the error model's",
        help="Base radius r.",
    ),
    delta: float | None = model_option(
        SweepSection, "delta", "--delta", none="the error model's",
        help="Base Delta.",
    ),
    eps_w: str | None = model_option(
        SweepSection, "eps_w", "--eps-w", none="max; 0.01 without an error model",
        help="Base disturbance bound eps_w: a number, max or pNN of the training flights' realized "
        "disturbance.",
    ),
    q: str | None = model_option(SweepSection, "Q", "--Q", help="Base state weight diagonal."),
    r: str | None = model_option(SweepSection, "R", "--R", help="Base input weight diagonal."),
    out: Path = typer.Option(
        ..., "--out", "-o", help="Output folder (sweep.parquet, sweep.csv, figures)."
    ),
    model: Path | None = typer.Option(
        None,
        "--model",
        "-m",
        help="error_model.yaml or fit folder (needed when S/eps_e are names).",
    ),
    jobs: int | None = model_option(
        SweepSection, "jobs", "--jobs", "-j", none="all cores", help="Local worker processes."
    ),
    scheduler: str | None = model_option(
        SweepSection, "scheduler", "--scheduler", none="none: local processes",
        help="Dask scheduler address, e.g. tcp://127.0.0.1:8786 (instead of --jobs).",
    ),
    wait_workers: float | None = model_option(
        SweepSection, "wait_workers", "--wait-workers",
        help="With --scheduler: seconds to wait for a first worker, and for one to come back when all "
        "have left, before giving up.",
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
) -> None:
    """A grid of robust syntheses (feasibility map), locally or on a Dask cluster."""
    from qsls.cli.common import RichProgress
    from qsls.pipeline.control.sweep import SweepSection, check_scheduler, sweep
    from qsls.pipeline.core.config import merge, read_section, validate
    from qsls.pipeline.core.errors import ConfigError

    if jobs is not None and scheduler is not None:
        raise ConfigError("give --jobs or --scheduler, not both")
    axes = dict(grid_axis(g) for g in grid or [])
    given = overrides(
        T=horizon, norm=norm, cost=cost, S=number_or_name(s), eps_e=number_or_name(eps_e),
        radius=radius, delta=delta, eps_w=number_or_name(eps_w), grid=axes or None,
        Q=parse_list(q, "--Q"), R=parse_list(r, "--R"), jobs=jobs,
        scheduler=None if scheduler is None else check_scheduler(scheduler),
        wait_workers=wait_workers,
    )  # fmt: skip
    data = read_section(config, "sweep")
    if jobs is not None or scheduler is not None:  # the command line's executor replaces the file's
        data = {k: v for k, v in data.items() if k not in ("jobs", "scheduler")}
    section = validate(SweepSection, merge(data, given), str(config or "options"))
    with RichProgress() as progress:
        result = sweep(
            section.options(), out, error_model=model, force=force, progress=progress,
            jobs=section.jobs, scheduler=section.scheduler, worker_timeout=section.wait_workers,
        )  # fmt: skip
    print_summary("sweep", result.summary())
