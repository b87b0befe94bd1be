"""The plan of the last run, reused while nothing it was made from changed.

Planning a config validates every stage's options with the stage's own model, which
imports the stage's module (the solver, scipy, pandas, matplotlib, RotorPy: about a second).
The validated options are a function of the config, the folder its paths are relative to,
the run folder and the qsls sources (the option models and their defaults); the run state
keeps them as plain JSON (:class:`qsls.pipeline.run.state.Plan`) under a fingerprint of
those. When the fingerprint is unchanged :func:`planned_graph` rebuilds the same stage
graph from that record: the same ids, dependencies, external inputs and options, so the
same cache keys, and a stage that has to run asks for the real plan then (:func:`lazy`).
Anything else (an edited config, an edited qsls source file, another folder) plans anew.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from qsls.pipeline.core.artifacts import sha256_json, to_plain
from qsls.pipeline.run.graph import Stage, StageGraph
from qsls.pipeline.run.state import Plan, RunState


def source_stamp() -> list[tuple[str, int, int]]:
    """(path, size, mtime) of every qsls pipeline source file: an edit plans anew."""
    top = Path(__file__).resolve().parents[1]
    out = []
    for dirpath, dirnames, filenames in os.walk(top):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith((".", "__")))
        for name in sorted(f for f in filenames if f.endswith(".py")):
            path = os.path.join(dirpath, name)
            st = os.stat(path)
            out.append((os.path.relpath(path, top), st.st_size, st.st_mtime_ns))
    return out


def fingerprint(config: Any, base: Path, root: Path, versions: Mapping[str, str]) -> str:
    """What the plan of ``config`` (paths relative to ``base``, run folder ``root``) depends on."""
    return sha256_json(
        {
            "config": config.record() if hasattr(config, "record") else to_plain(config),
            "base": str(Path(base).resolve()),
            "root": str(Path(root).resolve()),
            "versions": dict(versions),
            "sources": source_stamp(),
        }
    )


def planned_graph(
    root: Path, fingerprint: str, build: Callable[[], StageGraph], versions: Mapping[str, str]
) -> StageGraph:
    """The stage graph of the last run when its plan has ``fingerprint`` (and its external
    inputs still exist, so a missing one is reported by the planner); else ``build()``."""
    plan = RunState.load(root).plan
    if plan is None or plan.fingerprint != fingerprint or not _inputs_exist(plan):
        graph = build()
        graph.fingerprint, graph.versions = fingerprint, dict(versions)
        return graph
    return lazy(root, plan, build, versions)


def _inputs_exist(plan: Plan) -> bool:
    return all(os.path.exists(p) for s in plan.stages for p in s.external)


def lazy(
    root: Path, plan: Plan, build: Callable[[], StageGraph], versions: Mapping[str, str]
) -> StageGraph:
    """A graph with ``plan``'s stages whose ``execute`` and ``notes`` are the real stages'
    (from ``build()``, called once, when the first stage has to run)."""
    real: list[StageGraph] = []

    def stage(stage_id: str) -> Stage:
        if not real:
            real.append(build())
        return {s.id: s for s in real[0].stages}[stage_id]

    def execute(stage_id: str) -> Callable[[Path, Mapping[str, Path]], Any]:
        return lambda out, deps: stage(stage_id).execute(out, deps)

    def notes(stage_id: str) -> Callable[[Path], Mapping[str, Any]]:
        def call(out: Path) -> Mapping[str, Any]:
            s = stage(stage_id)
            return s.notes(out) if s.notes is not None else {}

        return call

    graph = StageGraph(Path(root), versions=dict(versions), fingerprint=plan.fingerprint)
    for p in plan.stages:
        graph.add(
            Stage(
                p.id,
                p.kind,
                p.options,
                execute(p.id),
                deps=tuple(p.deps),
                external=tuple(Path(e) for e in p.external),
                notes=notes(p.id),
            )
        )
    return graph
