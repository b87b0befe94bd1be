"""The ``qsls`` command: one subcommand per pipeline stage."""

from __future__ import annotations

import gc
import importlib
import os

# No pydantic plugins in the command: pydantic looks them up (every installed package's
# entry points read and parsed) when the first model is built, 5-10 ms of every command's
# start, and qsls installs none. Typer already builds its option adapters without them. A
# user who sets the variable (e.g. to a list of plugins to skip) keeps their value.
os.environ.setdefault("PYDANTIC_DISABLE_PLUGINS", "__all__")

import typer

# (command name, module in qsls.cli). Each module defines ``command`` whose docstring's
# first line is the summary shown by ``qsls --help``. Heavy imports stay inside commands.
COMMANDS: tuple[tuple[str, str], ...] = (
    ("simulate", "simulate"),
    ("ingest", "ingest"),
    ("fit", "fit"),
    ("synth", "synth"),
    ("sweep", "sweep"),
    ("calibrate", "calibrate"),
    ("evaluate", "evaluate"),
    ("fly", "fly"),
    ("export", "export"),
    ("replay", "replay"),
    ("verify", "verify"),
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


def _register(only: str | None = None) -> None:
    for name, module in COMMANDS:
        if only is not None and name != only:
            continue
        mod = importlib.import_module(f"qsls.cli.{module}")
        example = getattr(mod, "EXAMPLE", None)
        parts = [f"\b\nExample:\n  {example}"] if example else []
        config_only = getattr(mod.command, "__qsls_config_only__", None)  # fields.CONFIG_ONLY
        if config_only:
            from qsls.cli.fields import config_only_text

            parts.append(config_only_text(config_only))
        epilog = "\n\n".join(parts) or None
        app.command(name, epilog=epilog, cls=getattr(mod, "Command", None))(mod.command)


def _invoked() -> str | None:
    """The command named on a ``qsls`` command line (``qsls ingest ...``, or ``python -m
    qsls.cli.main ingest ...``), else None. Only that command is then registered: importing
    the other command modules and building their options is ~15 ms of a fresh process, and
    neither the command's run, its ``--help`` nor its errors involve the others. ``qsls``,
    ``qsls --help`` and an unknown command (whose error suggests the near names) register
    all; so does an import of this module (tests' CliRunner)."""
    import sys

    entry = __name__ == "__main__" or os.path.basename(sys.argv[0]) == "qsls"
    if not entry or len(sys.argv) < 2:
        return None
    return sys.argv[1] if sys.argv[1] in dict(COMMANDS) else None


_register(_invoked())


def main() -> None:
    try:
        app()
    finally:
        # The process ends here. Python's shutdown collects cyclic garbage as it clears
        # each module, walking every object the imports made (numpy, pyarrow, pydantic's
        # schemas) again and again: frozen, they are skipped (qsls ingest's exit 48 ->
        # 15 ms). Objects are still released by their reference counts, and atexit
        # handlers and weakref finalizers (dask's cluster, temporary folders) still run;
        # only a finalizer on an object left in a reference cycle would not. qsls writes
        # every output through a writer it closes itself (StageWriter, atomic files).
        gc.freeze()


if __name__ == "__main__":
    main()
