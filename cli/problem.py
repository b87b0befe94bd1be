"""The synthesis problem's options on the command line, declared once for ``qsls synth`` and
``qsls sweep`` (the fields of :class:`qsls.pipeline.control.options.ProblemOptions`; their
help and defaults come from the model, docs/cli.md)."""

from __future__ import annotations

from qsls.cli.fields import Table

PROBLEM: Table = {
    "T": ("--T", "-T"),
    "norm": ("--norm",),
    "cost": ("--cost",),
    "robust": ("--robust/--no-robust",),
    "strictly_proper": ("--strictly-proper/--not-strictly-proper",),
    "S": ("--S",),
    "eps_e": ("--eps-e",),
    "radius": ("--radius", "-r"),
    "delta": ("--delta",),
    "eps_w": ("--eps-w",),
    "eps_b": ("--eps-b",),
    "measure": ("--measure",),
    "beta": ("--beta",),
    "eps_o": ("--eps-o",),
    "gate": ("--gate",),
    "m": ("--m",),
    "error_scale": ("--error-scale",),
    "Q": ("--Q",),
    "R": ("--R",),
    "mass": ("--mass",),
    "dt": ("--dt",),
    "imitate": ("--imitate",),
    "solver": ("--solver",),
    "plant": ("--plant",),
    "H": ("--H",),
    "R0": ("--R0",),
    "outlier_risk": ("--outlier-risk",),
}
"""Each exposed field of the problem and its flags."""

PROBLEM_CONFIG_ONLY = {
    "eps_groups": "a mapping per channel group",
    "pd": "the PD's gains, a mapping",
}
"""The problem's fields a config file sets (mappings the command line does not spell)."""
