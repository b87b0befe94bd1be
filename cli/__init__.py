"""qsls.cli: the ``qsls`` command (Typer). Thin: parse, call one pipeline function, print."""
