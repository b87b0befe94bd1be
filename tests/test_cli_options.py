"""The option models are the single source of defaults: every stage option of a command is a field
of that stage's model, and the command line gives ``None`` (not given) unless the user sets it, so
the model's default (or the config file's value) always applies."""

from __future__ import annotations

import importlib

import pytest
from typer.main import get_command

from qsls.cli.main import app

# command -> (options model, command-line flags that are not stage options, flag -> field)
MODELS = {
    "ingest": ("qsls.pipeline.ingest.stage:IngestOptions", {"--vio", "--truth"}, {}),
    "fit": ("qsls.pipeline.errormodel.fit:FitOptions", set(), {"--no-figures": "figures"}),
    "synth": ("qsls.pipeline.control.synth:SynthOptions", {"--model", "--max-feasible-s"}, {}),
    "sweep": (
        "qsls.pipeline.control.sweep:SweepSection",
        {"--model"},
        {},
    ),
    "evaluate": (
        "qsls.pipeline.evaluate.options:EvaluateOptions",
        {"--model", "--controller", "--flights"},
        {"--no-figures": "figures"},
    ),
    "fly": (
        "qsls.pipeline.fly.options:FlyOptions",
        {"--model", "--controller"},
        {"--no-figures": "figures", "--backend": "sim.controller.backend"},
    ),
    "simulate": ("qsls.pipeline.sim.simulate:SimOptions", {"--format"}, {}),
    "export": ("qsls.pipeline.export.options:ExportOptions", set(), {}),
    "replay": ("qsls.pipeline.export.options:ReplayOptions", set(), {}),
}
COMMON = {"--out", "--config", "--force"}


def _model(spec: str):
    module, name = spec.split(":")
    return getattr(importlib.import_module(module), name)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_every_stage_option_is_a_model_field_and_defers_to_it(name):
    spec, extra, renamed = MODELS[name]
    model = _model(spec)
    fields = set(model.model_fields)
    nested = {f for f in fields if hasattr(model.model_fields[f].annotation, "model_fields")}
    sub = get_command(app).commands[name]
    checked = 0
    for p in sub.params:
        flag = next((o for o in p.opts if o.startswith("--")), None)
        if flag is None or flag in COMMON | extra:
            continue
        field = renamed.get(flag, flag[2:].replace("-", "_"))
        *path, leaf = field.split(".")
        owner = model
        for part in path:
            owner = owner.model_fields[part].annotation
        owners = (
            [owner]
            if path
            else [model] + [model.model_fields[f].annotation for f in sorted(nested)]
        )
        assert any(leaf in m.model_fields for m in owners), (
            f"qsls {name} {flag}: no field '{field}' in {model.__name__}"
        )
        if p.is_flag and p.default is False and flag.startswith("--no-"):
            continue  # a switch that only ever turns the model's default off
        assert p.default is None, f"qsls {name} {flag}: default {p.default!r} overrides the model"
        checked += 1
    assert checked >= 3
