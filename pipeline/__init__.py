"""qsls.pipeline: the library behind the ``qsls`` command (no printing, no sys.exit)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("qsls")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
