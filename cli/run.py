"""``qsls run``: the whole pipeline from one YAML config, cached stage by stage."""

from __future__ import annotations

from pathlib import Path

import typer

from qsls.cli.common import RichProgress, cli_errors, print_summary, print_verdicts
from qsls.pipeline.run.state import FIRST_RUN

EXAMPLE = "qsls run configs/quickstart.yaml --from fit"


STAGES = ("simulate", "ingest", "fit", "sweep", "synth", "calibrate", "evaluate", "fly",
          "report")  # fmt: skip
"""What ``--from`` takes: every stage kind of a run, in order (tests/test_run_words.py checks
it against the runner's)."""


def stage_line(
    stage_id: str, status: str, i: int, n: int, reason: str, elapsed: float, total: float
) -> str | None:
    """The console line of a finished stage: ``[i/n] id  done|up to date  (t s, T s in
    all)``, ``t`` the stage's own time and ``T`` the run's so far, and why it ran when that is
    news (a change, a missing output; not a first run)."""
    if status == "running":
        return None
    mark = {"ran": "done", "skipped": "up to date"}.get(status, status)
    why = f"  ran: {reason}" if status == "ran" and reason and reason != FIRST_RUN else ""
    return f"[{i + 1}/{n}] {stage_id:<24} {mark:<11} ({elapsed:6.1f} s, {total:.1f} s in all){why}"


@cli_errors
def command(
    config: Path = typer.Argument(..., help="Run config (YAML), e.g. configs/quickstart.yaml."),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="Run folder. Default: the config's 'out', or runs/<name>."
    ),
    force: bool = typer.Option(False, "--force", help="Redo every stage, even those up to date."),
    from_stage: str | None = typer.Option(
        None,
        "--from",
        help=f"Redo from this stage on: {', '.join(STAGES[:-1])} or {STAGES[-1]}.",
    ),
) -> None:
    """Run the pipeline a config names (simulate, ingest, fit, sweep, synth, calibrate,
    evaluate, fly, report)."""
    import time

    from qsls.pipeline.run.runner import run

    t0 = time.perf_counter()
    started: dict[str, float] = {}

    def on_stage(stage_id: str, status: str, i: int, n: int, reason: str) -> None:
        now = time.perf_counter()
        if status == "running":
            started[stage_id] = now
        own = now - started.get(stage_id, now)
        line = stage_line(stage_id, status, i, n, reason, own, now - t0)
        if line is not None:
            progress.note(line)

    with RichProgress() as progress:
        result = run(
            config,
            out=out,
            force=force,
            from_stage=from_stage,
            progress=progress,
            on_stage=on_stage,
        )
    print_summary("qsls run", result.summary())
    notes = {oc.id: oc.notes for oc in result.outcomes}  # recorded when each stage ran
    for stage, note in notes.items():
        for w in note.get("warnings", []):
            typer.echo(f"warning: {stage}: {w}", err=True)
    print_verdicts("Calibrated certificates", notes.get("calibrate", {}).get("calibrated", []))
    for stage, title in (("evaluate", "held-out flights"), ("fly", "flown flights")):
        lines = notes.get(stage, {}).get("verdicts", [])
        print_verdicts(f"Certified bound on the {title}", lines)
