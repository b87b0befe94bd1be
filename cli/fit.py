"""``qsls fit``: the perception error model (eps_e, S-slope, delta) of ingested flights."""

from __future__ import annotations

from pathlib import Path

import typer

from qsls.cli.common import cli_errors, model_option, overrides, parse_list
from qsls.pipeline.errormodel.options import FitOptions

EXAMPLE = "qsls fit flights/f1 flights/f2 --out fit --radius 1.0"


@cli_errors
def command(
    flights: list[Path] = typer.Argument(
        None,
        help="Flight folders written by 'qsls ingest' (the training data).",
        show_default=False,
    ),
    out: Path = typer.Option(
        ..., "--out", "-o", help="Output folder (error_model.yaml, training_states.parquet, PNGs)."
    ),
    radius: float = model_option(FitOptions, "radius", "--radius", "-r"),
    percentiles: str = model_option(
        FitOptions, "percentiles", "--percentiles",
        help="Comma-separated percentiles of ||e||, pair slopes and per-sample largest slopes.",
    ),
    min_separation: str = model_option(
        FitOptions, "min_separation", "--min-separation",
        help="Leave out pairs closer than this (a number, or 'auto' = 3 x the noise floor of e "
        "estimated from the data): below the measurement noise, slopes are noise / distance and "
        "blow up. 0 keeps every pair at a positive distance.",
    ),
    state_scale: str = model_option(
        FitOptions, "state_scale", "--state-scale",
        help="Six comma-separated weights of px,py,pz,vx,vy,vz in the state distance.",
    ),
    exclude_outliers: bool = model_option(
        FitOptions, "exclude_outliers", "--exclude-outliers/--keep-outliers",
        help="Leave out samples whose robust z-score of e (median/MAD) exceeds --outlier-z on "
        "some axis; the count is reported.",
    ),
    outlier_z: float = model_option(FitOptions, "outlier_z", "--outlier-z"),
    skip_start: float = model_option(FitOptions, "skip_start", "--skip-start"),
    reference: str = model_option(
        FitOptions, "reference", "--reference", none="none, delta = 0",
        help="Reference for delta (max distance from its states to the nearest training state): "
        "'circle:radius=1,height=1,period=5' (the simulator's reference options: kind circle, "
        "hover or figure8; radius, height, period, laps, ramp_s, center=X;Y) or a flight folder.",
    ),
    reference_lead_in: bool = model_option(
        FitOptions, "reference_lead_in", "--reference-lead-in/--reference-pattern-only",
        help="Include a parametric reference's take-off and approach in delta, or only its "
        "pattern.",
    ),
    r0: str = model_option(FitOptions, "r0", "--r0"),
    bootstrap: int = model_option(
        FitOptions, "bootstrap", "--bootstrap",
        help="Bootstrap replicates for confidence intervals (moving blocks within each flight; "
        "costs about N times the pair pass).",
    ),
    bootstrap_block: int = model_option(FitOptions, "bootstrap_block", "--bootstrap-block"),
    seed: int = model_option(FitOptions, "seed", "--seed"),
    jobs: int = model_option(FitOptions, "jobs", "--jobs", "-j"),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the PNG figures."),
    config: Path = typer.Option(
        None, "--config", "-c", help="YAML file of these options (its 'fit' section, or all)."
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output folder."),
) -> None:
    """Estimate the perception error model (eps_e, S-slope, delta) from ingested flights."""
    from qsls.cli.common import RichProgress, print_summary
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.errormodel.fit import fit

    given = overrides(
        radius=radius, percentiles=parse_list(percentiles, "--percentiles"),
        min_separation=_minsep(min_separation), state_scale=parse_list(state_scale, "--state-scale"),
        exclude_outliers=exclude_outliers, outlier_z=outlier_z, skip_start=skip_start,
        reference=reference, reference_lead_in=reference_lead_in, r0=r0, bootstrap=bootstrap,
        bootstrap_block=bootstrap_block, seed=seed, jobs=jobs,
        figures=False if no_figures else None,
    )  # fmt: skip
    options = load_options(FitOptions, config, given, section="fit")
    with RichProgress() as progress:
        result = fit(list(flights or []), options, out, force=force, progress=progress)
    print_summary("qsls fit", result.summary())
    _print_worst_pairs(result.model.worst_pairs[:5])


def _print_worst_pairs(wp: list) -> None:
    from qsls.cli.common import print_table

    if not wp:
        return
    print_table(
        "Largest slopes (the pairs that set S)",
        ["slope", "distance", "flight i", "t_i", "flight j", "t_j", "||e_i - e_j||"],
        [
            (
                w.slope,
                w.distance,
                w.flight,
                round(w.t_i, 3),
                w.flight_j or w.flight,
                round(w.t_j, 3),
                max(abs(a - b) for a, b in zip(w.e_i, w.e_j, strict=True)),
            )
            for w in wp
        ],
    )


def _minsep(text: str | None) -> float | str | None:
    if text is None or text.strip().lower() == "auto":
        return None if text is None else "auto"
    try:
        return float(text)
    except ValueError:
        from qsls.pipeline.core.errors import ConfigError

        raise ConfigError(f"--min-separation: expected 'auto' or a number, got {text!r}") from None
