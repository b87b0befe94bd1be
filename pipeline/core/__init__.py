"""Shared foundations: stage folders and atomic writes, option models, errors, progress, the
plant model, reference trajectories, units and rotations (what every stage needs)."""

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
        "LinearModel": "plant",
        "quadrotor_model": "plant",
        "Reference": "references",
        "ReferenceOptions": "references",
        "NULL_PROGRESS": "progress",
    },
)
