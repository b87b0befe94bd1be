"""A small cached stage graph: run stages in order, skip those whose inputs did not change.

Each :class:`Stage` has a key: the sha256 of its kind, its options, its external input
files' hashes and the keys of the stages it depends on. After a stage succeeds its key is
recorded in ``RUN_DIR/run_state.json`` (written atomically). On a rerun a stage whose folder
exists and whose recorded key equals its current key is skipped; a changed option changes
that stage's key and therefore every key downstream of it, so exactly those stages rerun.

A stage killed mid-way leaves no folder (stages write through ``StageWriter``) and no key,
so the next run redoes it and nothing before it.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from qsls.pipeline.core.artifacts import atomic_write_bytes, sha256_json, sha256_path, to_plain
from qsls.pipeline.core.errors import ConfigError

STATE_FILE = "run_state.json"


@dataclass(frozen=True)
class Stage:
    """One node: ``execute(out, deps)`` writes ``out`` (``deps`` maps dep id to its folder)."""

    id: str
    kind: str
    options: Any
    execute: Callable[[Path, Mapping[str, Path]], Any]
    deps: tuple[str, ...] = ()
    external: tuple[Path, ...] = ()


@dataclass(frozen=True)
class StageOutcome:
    id: str
    kind: str
    status: str  # "ran" | "skipped"
    key: str
    folder: Path
    result: Any = None


@dataclass
class StageGraph:
    root: Path
    stages: list[Stage] = field(default_factory=list)

    def add(self, stage: Stage) -> Stage:
        if any(s.id == stage.id for s in self.stages):
            raise ConfigError(f"two stages are named '{stage.id}'")
        missing = [d for d in stage.deps if d not in self.ids]
        if missing:
            raise ConfigError(f"stage '{stage.id}' depends on unknown stage(s) {missing}")
        self.stages.append(stage)
        return stage

    @property
    def ids(self) -> list[str]:
        return [s.id for s in self.stages]

    def folder(self, stage_id: str) -> Path:
        return self.root / stage_id

    def keys(self) -> dict[str, str]:
        """Every stage's cache key, in topological (insertion) order."""
        keys: dict[str, str] = {}
        for s in self.stages:
            keys[s.id] = sha256_json(
                {
                    "kind": s.kind,
                    "options": to_plain(s.options),
                    "external": [sha256_path(p) for p in s.external],
                    "deps": [keys[d] for d in s.deps],
                }
            )
        return keys

    def downstream(self, stage_ids: Sequence[str]) -> set[str]:
        """The given stages and everything that depends on them, transitively."""
        out = set(stage_ids)
        for s in self.stages:
            if any(d in out for d in s.deps):
                out.add(s.id)
        return out

    def run(
        self,
        *,
        force: bool = False,
        from_kind: str | None = None,
        on_start: Callable[[Stage, int, int], None] | None = None,
        on_done: Callable[[StageOutcome, int, int], None] | None = None,
    ) -> list[StageOutcome]:
        """Run what is out of date; ``force`` reruns all, ``from_kind`` reruns from that kind on."""
        keys = self.keys()
        state = read_state(self.root)
        redo: set[str] = set()
        if force:
            redo = set(self.ids)
        elif from_kind is not None:
            kinds = [s.kind for s in self.stages]
            if from_kind not in kinds:
                raise ConfigError(
                    f"--from {from_kind}: this run has no such stage (it has: {', '.join(dict.fromkeys(kinds))})"
                )
            first = kinds.index(from_kind)
            redo = self.downstream([s.id for s in self.stages[first:] if s.kind == from_kind])
            redo |= {s.id for s in self.stages[first:]}
        outcomes = []
        n = len(self.stages)
        for i, s in enumerate(self.stages):
            out = self.folder(s.id)
            up_to_date = (
                s.id not in redo
                and state.get(s.id) == keys[s.id]
                and (out / "manifest.json").is_file()
            )
            if up_to_date:
                oc = StageOutcome(s.id, s.kind, "skipped", keys[s.id], out)
            else:
                if on_start:
                    on_start(s, i, n)
                deps = {d: self.folder(d) for d in s.deps}
                result = s.execute(out, deps)
                state[s.id] = keys[s.id]
                write_state(self.root, state)
                oc = StageOutcome(s.id, s.kind, "ran", keys[s.id], out, result)
            outcomes.append(oc)
            if on_done:
                on_done(oc, i, n)
        return outcomes


def read_state(root: Path) -> dict[str, str]:
    p = Path(root) / STATE_FILE
    if not p.is_file():
        return {}
    try:
        data = json.loads(p.read_text())
    except json.JSONDecodeError:
        return {}
    return dict(data.get("stages", {}))


def write_state(root: Path, stages: Mapping[str, str]) -> None:
    body = json.dumps({"stages": dict(stages)}, indent=2, sort_keys=True) + "\n"
    atomic_write_bytes(Path(root) / STATE_FILE, body.encode())
