"""A small cached stage graph: run stages in order, skip those whose inputs did not change.

Each :class:`Stage` has a key: the sha256 of its kind, its options, its external input
files' hashes and the keys of the stages it depends on. After a stage succeeds its key is
recorded in ``RUN_DIR/run_state.json`` (:class:`qsls.pipeline.run.state.RunState`, written
atomically) together with the sha256, size and mtime of every file of its folder. On a rerun
a stage is skipped only when its recorded key equals its current key and its folder still
holds those files (size and mtime first, the hash when they differ); a changed option
changes that stage's key and therefore every key downstream of it, and a stage that runs
makes every stage after it run, so exactly those stages rerun.

A stage killed mid-way leaves no folder (stages write through ``StageWriter``) and no
record, so the next run redoes it and nothing before it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from qsls.pipeline.core.artifacts import sha256_json, sha256_path, to_plain
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.run.state import RunState, StageRecord


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
    reason: str = ""  # why it ran: "not run yet", "output fit/error_model.yaml is missing", ...


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
        """Run what is out of date; ``force`` reruns all, ``from_kind`` reruns from that kind on.

        A stage is out of date when its key changed, its recorded outputs are missing or
        changed (:class:`RunState`), or a stage it depends on ran in this run.
        """
        keys = self.keys()
        state = RunState.load(self.root)
        asked = self._redo(force, from_kind)
        after: dict[str, str] = {}  # stages after one that ran, and which
        outcomes = []
        n = len(self.stages)
        for i, s in enumerate(self.stages):
            out = self.folder(s.id)
            why = asked.get(s.id) or state.why_stale(s.id, keys[s.id], out) or after.get(s.id)
            if why is None:
                oc = StageOutcome(s.id, s.kind, "skipped", keys[s.id], out)
            else:
                if on_start:
                    on_start(s, i, n)
                state = state.without({s.id})
                state.save(self.root)  # a stage being redone is not up to date until it ends
                result = s.execute(out, {d: self.folder(d) for d in s.deps})
                state = state.with_stage(s.id, StageRecord.of_folder(keys[s.id], out))
                state.save(self.root)
                for t in self.stages:  # its dependents run, and then theirs
                    if s.id in t.deps:
                        after.setdefault(t.id, f"{s.id} ran")
                oc = StageOutcome(s.id, s.kind, "ran", keys[s.id], out, result, why)
            outcomes.append(oc)
            if on_done:
                on_done(oc, i, n)
        return outcomes

    def _redo(self, force: bool, from_kind: str | None) -> dict[str, str]:
        """The stages asked to run again, with why."""
        if force:
            return dict.fromkeys(self.ids, "--force")
        if from_kind is None:
            return {}
        kinds = [s.kind for s in self.stages]
        # a kind (evaluate: the bound check and fly) or a stage's own id (fly)
        hits = [i for i, s in enumerate(self.stages) if from_kind in (s.kind, s.id)]
        if not hits:
            raise ConfigError(
                f"--from {from_kind}: this run has no such stage (it has: {', '.join(dict.fromkeys(kinds))})"
            )
        first = hits[0]
        redo = self.downstream([self.stages[i].id for i in hits])
        return dict.fromkeys(
            sorted(redo | {s.id for s in self.stages[first:]}), f"--from {from_kind}"
        )
