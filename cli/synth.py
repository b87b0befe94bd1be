"""``qsls synth``: robust SLS controllers from an error model, each with a certificate."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from qsls.cli.common import cli_errors, number_or_name, overrides, parse_list, print_summary

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
    horizon: int | None = typer.Option(
        None, "--T", "-T", help="FIR horizon T (taps 0..T), 2 to 500. (default: 20)"
    ),
    norm: str | None = typer.Option(
        None, "--norm", help="l1, h2 or both (the H2 variants too). (default: l1)"
    ),
    controllers: str | None = typer.Option(
        None,
        "--controllers",
        help="paper (pd + nominal, robust, robust imitation) or single. (default: paper)",
    ),
    cost: str | None = typer.Option(
        None, "--cost", help="qr or imitation (controllers: single). (default: qr)"
    ),
    robust: bool | None = typer.Option(
        None,
        "--robust/--no-robust",
        help="Impose the robustness constraint (controllers: single). (default: --robust)",
    ),
    strictly_proper: bool | None = typer.Option(
        None,
        "--strictly-proper/--not-strictly-proper",
        help="u[k] from y up to k-1 only (Phi_uy(0) = 0). (default: --not-strictly-proper)",
    ),
    s: str | None = typer.Option(
        None,
        "--S",
        help="S-slope: a number, lofo (leave-one-flight-out) or an error-model name (max, p95, local_p99). (default: lofo)",
    ),
    eps_e: str | None = typer.Option(
        None, "--eps-e", help="Error bound: a number or a name (max, p99, R0). (default: max)"
    ),
    radius: float | None = typer.Option(
        None, "--radius", "-r", help="Radius r. (default: the error model's)"
    ),
    delta: float | None = typer.Option(None, "--delta", help="Delta. (default: the error model's)"),
    eps_w: str | None = typer.Option(
        None,
        "--eps-w",
        help="Disturbance bound eps_w: a number, max or pNN of the training flights' realized "
        "disturbance. (default: max; 0.01 without an error model)",
    ),
    measure: str | None = typer.Option(
        None, "--measure", help="Error channels read: full or position. (default: full)"
    ),
    beta: float | None = typer.Option(
        None,
        "--beta",
        help="Clip of the velocity errors' dense part; what it clips off is an outlier. "
        "(default: none)",
    ),
    eps_o: float | None = typer.Option(
        None, "--eps-o", help="Bound on one outlier (a physical bound). (default: none)"
    ),
    gate: float | None = typer.Option(
        None, "--gate", help="Velocity gate V: eps_o = 2V - beta. (default: none)"
    ),
    m: str | None = typer.Option(
        None, "--m", help="Outliers per window of T steps: a number or auto. (default: auto)"
    ),
    error_scale: str | None = typer.Option(
        None, "--error-scale", help="W_e: 6 weights of the error norm. (default: 1,1,1,1,1,1)"
    ),
    q: str | None = typer.Option(
        None, "--Q", help="State weight diagonal. (default: 10,10,10,1,1,1)"
    ),
    r: str | None = typer.Option(None, "--R", help="Input weight diagonal. (default: 1,1,0.1)"),
    mass: float | None = typer.Option(None, "--mass", help="Vehicle mass in kg. (default: 0.256)"),
    dt: float | None = typer.Option(None, "--dt", help="Controller period in s. (default: 0.1)"),
    imitate: str | None = typer.Option(
        None,
        "--imitate",
        help="Imitation target: pd, l1_nominal, h2_nominal or a controller folder. (default: pd)",
    ),
    solver: str | None = typer.Option(
        None, "--solver", help="cvxpy solver name. (default: CLARABEL)"
    ),
    max_feasible_s: bool = typer.Option(
        False,
        "--max-feasible-s",
        help="Only compute the largest feasible S for this setting and print it.",
    ),
) -> None:
    """Robust SLS controllers from an error model, each with a certificate."""
    from qsls.cli.common import RichProgress
    from qsls.pipeline.control.synth import SynthOptions, synth
    from qsls.pipeline.control.synth import max_feasible_s as compute_max_s
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
