"""``qsls synth``: robust SLS controllers from an error model, each with a certificate."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import (
    cli_errors,
    model_option,
    number_or_name,
    overrides,
    parse_list,
    print_summary,
)
from qsls.pipeline.control.options import SynthOptions

EXAMPLE = "qsls synth --model fit --out controllers --T 20 --S p50 --eps-e p95"


@cli_errors
def command(
    model: Path | None = typer.Option(
        None, "--model", "-m", help="error_model.yaml or the fit folder holding it (qsls fit)."
    ),
    config: Path | None = typer.Option(None, "--config", "-c", help="YAML file of synth options."),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="Output folder (one sub-folder per controller)."
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
    horizon: int | None = model_option(
        SynthOptions, "T", "--T", "-T",
        help="FIR horizon T (taps 0..T), 2 to 500.",
    ),
    norm: str | None = model_option(
        SynthOptions, "norm", "--norm",
        help="l1, h2 or both (the H2 variants too).",
    ),
    controllers: str | None = model_option(
        SynthOptions, "controllers", "--controllers",
        help="paper (pd + nominal, robust, robust imitation) or single.",
    ),
    cost: str | None = model_option(
        SynthOptions, "cost", "--cost",
        help="qr or imitation (controllers: single).",
    ),
    robust: bool | None = model_option(
        SynthOptions, "robust", "--robust/--no-robust",
        help="Impose the robustness constraint (controllers: single).",
    ),
    strictly_proper: bool | None = model_option(
        SynthOptions, "strictly_proper", "--strictly-proper/--not-strictly-proper",
        help="u[k] from y up to k-1 only (Phi_uy(0) = 0).",
    ),
    s: str | None = model_option(
        SynthOptions, "S", "--S",
        help="S-slope: a number, lofo (leave-one-flight-out) or an error-model name (max, p95, "
        "local_p99).",
    ),
    eps_e: str | None = model_option(
        SynthOptions, "eps_e", "--eps-e",
        help="Error bound: a number or a name (max, p99, R0).",
    ),
    radius: float | None = model_option(
        SynthOptions, "radius", "--radius", "-r", none="the error model's",
        help="Radius r.",
    ),
    delta: float | None = model_option(
        SynthOptions, "delta", "--delta", none="the error model's",
        help="Delta.",
    ),
    eps_w: str | None = model_option(
        SynthOptions, "eps_w", "--eps-w", none="max; 0.01 without an error model",
        help="Disturbance bound eps_w: a number, max or pNN of the training flights' realized "
        "disturbance.",
    ),
    measure: str | None = model_option(
        SynthOptions, "measure", "--measure",
        help="Error channels read: full or position.",
    ),
    beta: float | None = model_option(
        SynthOptions, "beta", "--beta",
        help="Clip of the velocity errors' dense part; what it clips off is an outlier.",
    ),
    eps_o: float | None = model_option(
        SynthOptions, "eps_o", "--eps-o",
        help="Bound on one outlier (a physical bound).",
    ),
    gate: float | None = model_option(
        SynthOptions, "gate", "--gate",
        help="Velocity gate V: eps_o = 2V - beta.",
    ),
    m: str | None = model_option(
        SynthOptions, "m", "--m",
        help="Outliers per window of T steps: a number or auto.",
    ),
    error_scale: str | None = model_option(
        SynthOptions, "error_scale", "--error-scale",
        help="W_e: 6 weights of the error norm.",
    ),
    q: str | None = model_option(SynthOptions, "Q", "--Q", help="State weight diagonal."),
    r: str | None = model_option(SynthOptions, "R", "--R", help="Input weight diagonal."),
    mass: float | None = model_option(SynthOptions, "mass", "--mass", help="Vehicle mass in kg."),
    dt: float | None = model_option(SynthOptions, "dt", "--dt", help="Controller period in s."),
    imitate: str | None = model_option(
        SynthOptions, "imitate", "--imitate",
        help="Imitation target: pd, l1_nominal, h2_nominal or a controller folder.",
    ),
    solver: str | None = model_option(
        SynthOptions, "solver", "--solver",
        help="cvxpy solver name.",
    ),
    max_feasible_s: bool = typer.Option(
        False,
        "--max-feasible-s",
        help="Only compute the largest feasible S for this setting and print it.",
    ),
) -> None:
    """Robust SLS controllers from an error model, each with a certificate."""
    from qsls.cli.common import RichProgress
    from qsls.pipeline.control.synth import max_feasible_s as compute_max_s
    from qsls.pipeline.control.synth import synth
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.core.errors import ConfigError

    given: dict[str, Any] = overrides(
        T=horizon, norm=norm, controllers=controllers, cost=cost, robust=robust,
        strictly_proper=strictly_proper, S=number_or_name(s), eps_e=number_or_name(eps_e),
        radius=radius, delta=delta, eps_w=number_or_name(eps_w), Q=parse_list(q, "--Q"),
        R=parse_list(r, "--R"), mass=mass, dt=dt, imitate=imitate, solver=solver,
        measure=measure, beta=beta, eps_o=eps_o, gate=gate, m=number_or_name(m),
        error_scale=parse_list(error_scale, "--error-scale"),
    )  # fmt: skip
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
