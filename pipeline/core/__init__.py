"""Shared foundations: stage folders and atomic writes, option models, errors, progress."""

from qsls.pipeline.core.api import lazy_api

__all__, __getattr__ = lazy_api(
    __name__,
    {
        "StageWriter": "artifacts",
        "sha256_file": "artifacts",
        "read_manifest": "artifacts",
        "Options": "config",
        "load_options": "config",
        "QslsError": "errors",
        "InputError": "errors",
        "ConfigError": "errors",
        "OutputExistsError": "errors",
        "InfeasibleError": "errors",
        "SolverError": "errors",
        "Progress": "progress",
        "NULL_PROGRESS": "progress",
    },
)
