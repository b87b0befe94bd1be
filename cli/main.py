"""The ``qsls`` command: one subcommand per pipeline stage."""

from __future__ import annotations

import importlib
import importlib.util

import typer

# (command name, module in qsls.cli). Each module defines ``command`` whose docstring's
# first line is the summary shown by ``qsls --help``. Heavy imports stay inside commands.
COMMANDS: tuple[tuple[str, str], ...] = (
    ("simulate", "simulate"),
    ("ingest", "ingest"),
    ("fit", "fit"),
    ("synth", "synth"),
    ("sweep", "sweep"),
    ("evaluate", "evaluate"),
    ("export", "export"),
    ("replay", "replay"),
    ("report", "report"),
    ("run", "run"),
)

app = typer.Typer(
    name="qsls",
    help="Quadrotor flight logs to certified robust SLS controllers.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version(value: bool) -> None:
    if value:
        from qsls.pipeline import __version__

        typer.echo(f"qsls {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Show the version and exit."
    ),
) -> None:
    """Quadrotor flight logs to certified robust SLS controllers."""


def _register() -> None:
    for name, module in COMMANDS:
        full = f"qsls.cli.{module}"
        if importlib.util.find_spec(full) is None:
            continue  # a stage not built yet
        mod = importlib.import_module(full)
        example = getattr(mod, "EXAMPLE", None)
        epilog = f"\b\nExample:\n  {example}" if example else None
        app.command(name, epilog=epilog)(mod.command)


_register()


def main() -> None:
    app()


if __name__ == "__main__":
    main()
