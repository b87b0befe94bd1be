"""A small cached stage graph: run stages in order, skip those whose inputs did not change.

Each :class:`Stage` has a key: the sha256 of its kind, its options, its external input
files' hashes, the keys of the stages it depends on, and the versions of qsls and of the
numerical packages (those every manifest records: numpy, scipy, cvxpy, clarabel, rotorpy,
...; read with ``importlib.metadata``, nothing imported), so an upgraded solver reruns the
stages instead of serving a certificate it did not make. An external input is hashed again
only when one of its files changed size or mtime (:class:`InputHashes`). After a stage
succeeds its key is recorded in ``RUN_DIR/run_state.json``
(:class:`qsls.pipeline.run.state.RunState`, written atomically) together with the sha256,
size and mtime of every file of its folder and its ``notes`` (what the console reports about
it). On a rerun a stage is skipped only when its recorded key equals its current key and its
folder still holds those files (size and mtime first, the hash when they differ); a changed
option changes that stage's key and therefore every key downstream of it, and a stage that
runs makes every stage after it run, so exactly those stages rerun.

A stage killed mid-way leaves no folder (stages write through ``StageWriter``) and no
record, so the next run redoes it and nothing before it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from qsls.pipeline import __version__
from qsls.pipeline.core.artifacts import package_versions, sha256_json, to_plain
from qsls.pipeline.core.errors import ConfigError, QslsError
from qsls.pipeline.run.state import InputHashes, Plan, PlannedStage, RunState, StageRecord


def run_versions() -> dict[str, str]:
    """qsls's version and the numerical packages' (from their metadata, none imported)."""
    return {"qsls": __version__, **package_versions()}


@dataclass(frozen=True)
class Stage:
    """One node: ``execute(out, deps)`` writes ``out`` (``deps`` maps dep id to its folder).

    ``notes(out)``, called after it ran, gives what the console reports about it (kept in
    the run state); ``out`` is the run folder's ``id`` unless ``folder`` says otherwise."""

    id: str
    kind: str
    options: Any
    execute: Callable[[Path, Mapping[str, Path]], Any]
    deps: tuple[str, ...] = ()
    external: tuple[Path, ...] = ()
    notes: Callable[[Path], Mapping[str, Any]] | None = None
    folder: Path | None = None


@dataclass(frozen=True)
class StageOutcome:
    id: str
    kind: str
    status: str  # "ran" | "skipped"
    key: str
    folder: Path
    result: Any = None
    reason: str = ""  # why it ran: "not run yet", "output fit/error_model.yaml is missing", ...
    notes: Mapping[str, Any] = field(default_factory=dict)


@dataclass
class StageGraph:
    root: Path
    stages: list[Stage] = field(default_factory=list)
    versions: Mapping[str, str] = field(default_factory=run_versions)
    fingerprint: str = ""  # of what the stages were planned from (recorded as the plan)
    hashes: InputHashes = field(default_factory=InputHashes)  # the last keys()'s inputs

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

    def out(self, s: Stage) -> Path:
        """The folder stage ``s`` writes."""
        return s.folder if s.folder is not None else self.folder(s.id)

    def key(self, s: Stage, keys: Mapping[str, str]) -> str:
        """``s``'s cache key, given its dependencies' keys."""
        return sha256_json(
            {
                "kind": s.kind,
                "options": to_plain(s.options),
                "external": [self.hashes.digest(p) for p in s.external],
                "deps": [keys[d] for d in s.deps],
                "versions": dict(self.versions),
            }
        )

    def keys(self, state: RunState | None = None) -> dict[str, str]:
        """Every stage's cache key, in topological (insertion) order; input files are hashed
        again only where ``state`` recorded another size or mtime."""
        self.hashes = InputHashes(state.inputs if state is not None else None)
        keys: dict[str, str] = {}
        for s in self.stages:
            keys[s.id] = self.key(s, keys)
        return keys

    def plan(self) -> Plan:
        """The stages as data (what :mod:`qsls.pipeline.run.memo` rebuilds a graph from)."""
        return Plan(
            fingerprint=self.fingerprint,
            stages=[
                PlannedStage(
                    id=s.id,
                    kind=s.kind,
                    options=to_plain(s.options),
                    deps=list(s.deps),
                    external=[str(p) for p in s.external],
                )
                for s in self.stages
            ],
        )

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
        state = RunState.load(self.root)
        keys = self.keys(state)
        before = state
        state = state.with_inputs(self.hashes.records)
        if self.fingerprint:
            state = state.with_plan(self.plan())
        if state != before:
            state.save(self.root)
        asked = self._redo(force, from_kind)
        after: dict[str, str] = {}  # stages after one that ran, and which
        outcomes = []
        n = len(self.stages)
        for i, s in enumerate(self.stages):
            why = asked.get(s.id)
            if why is None:  # a stage asked to rerun needs no check of its outputs
                stale, state = self._stale(state, s, keys[s.id])
                why = stale or after.get(s.id)
            if why is not None and on_start:
                on_start(s, i, n)
            state, oc = self._run_one(state, s, keys[s.id], why)
            if oc.status == "ran":
                for t in self.stages:  # its dependents run, and then theirs
                    if s.id in t.deps:
                        after.setdefault(t.id, f"{s.id} ran")
            outcomes.append(oc)
            if on_done:
                on_done(oc, i, n)
        return outcomes

    def run_last(
        self,
        stage: Stage,
        outcomes: Sequence[StageOutcome],
        *,
        redo: str | None = None,
        on_start: Callable[[Stage], None] | None = None,
    ) -> StageOutcome:
        """Run ``stage``, which depends on every stage of the graph (the report), when it is
        out of date: ``redo`` given, a stage ran in ``outcomes``, its key or outputs changed."""
        state = RunState.load(self.root)
        keys = {oc.id: oc.key for oc in outcomes}
        key = self.key(stage, keys)
        ran = next((f"{oc.id} ran" for oc in outcomes if oc.status == "ran"), None)
        why = redo or ran
        if why is None:
            why, state = self._stale(state, stage, key)
        if why is not None and on_start:
            on_start(stage)
        return self._run_one(state, stage, key, why)[1]

    def _stale(self, state: RunState, s: Stage, key: str) -> tuple[str | None, RunState]:
        """Why ``s`` must run (or None), and ``state`` with its touched files restamped
        (saved at once: the next run then hashes them no more)."""
        why, checked = state.check(s.id, key, self.out(s), self.versions)
        if checked is not state:
            checked.save(self.root)
        return why, checked

    def _run_one(
        self, state: RunState, s: Stage, key: str, why: str | None
    ) -> tuple[RunState, StageOutcome]:
        out = self.out(s)
        if why is None:
            rec = state.stages[s.id]
            return state, StageOutcome(s.id, s.kind, "skipped", key, out, notes=rec.notes)
        state = state.without({s.id})
        state.save(self.root)  # a stage being redone is not up to date until it ends
        try:
            result = s.execute(out, {d: self.folder(d) for d in s.deps})
        except QslsError as exc:  # the one line names the stage that failed
            exc.args = (f"stage {s.id} failed: {exc}", *exc.args[1:])
            raise
        notes = dict(s.notes(out)) if s.notes is not None else {}
        state = state.with_stage(s.id, StageRecord.of_folder(key, out, self.versions, notes))
        state.save(self.root)
        return state, StageOutcome(s.id, s.kind, "ran", key, out, result, why, notes)

    def _redo(self, force: bool, from_kind: str | None) -> dict[str, str]:
        """The stages asked to run again, with why."""
        if force:
            return dict.fromkeys(self.ids, "--force")
        if from_kind is None:
            return {}
        kinds = [s.kind for s in self.stages]
        # a kind (evaluate, fly, ...) or a stage's own id (ingest/train_1)
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
