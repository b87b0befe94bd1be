"""``qsls synth``: robust SLS controllers from an error model, each with a certificate."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import cli_errors, print_summary
from qsls.cli.fields import model_options
from qsls.cli.problem import PROBLEM, PROBLEM_CONFIG_ONLY
from qsls.pipeline.control.options import SynthOptions

EXAMPLE = "qsls synth --model fit --out controllers --T 20 --S p50 --eps-e p95"


@cli_errors
@model_options(
    SynthOptions,
    {**PROBLEM, "controllers": ("--controllers",)},
    config_only={**PROBLEM_CONFIG_ONLY, "paper_mode": "the paper's setting, a mapping"},
)
def command(
    model: Path | None = typer.Option(
        None, "--model", "-m", help="error_model.yaml or the fit folder holding it (qsls fit)."
    ),
    config: Path | None = typer.Option(None, "--config", "-c", help="YAML file of synth options."),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="Output folder (one sub-folder per controller)."
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
    max_feasible_s: bool = typer.Option(
        False,
        "--max-feasible-s",
        help="Only compute the largest feasible S for this setting and print it.",
    ),
    *,
    given: dict[str, Any],
) -> None:
    """Robust SLS controllers from an error model, each with a certificate."""
    from qsls.cli.common import RichProgress
    from qsls.pipeline.control.synth import max_feasible_s as compute_max_s
    from qsls.pipeline.control.synth import synth
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.core.errors import ConfigError

    opts = load_options(SynthOptions, config, given, section="synth")
    if max_feasible_s:
        res = compute_max_s(model, opts)
        print_summary("largest feasible S", res.summary())
        return
    if out is None:
        raise ConfigError("--out is required (the folder to write the controllers to)")
    with RichProgress() as progress:
        result = synth(model, opts, out, force=force, progress=progress)
    print_summary("synth", result.summary())
