"""The run state (``RUN_DIR/run_state.json``): per stage, its cache key and its outputs.

A stage is up to date when its recorded key equals its current key *and* its folder still
holds the files it wrote: every recorded file exists with its recorded sha256. The check is
cheap: a file whose size and modification time are the recorded ones is taken as unchanged;
only a file whose size or time differs is hashed (a ``touch`` costs one hash, not a rerun).
The hashes come from the stage's ``manifest.json`` (written by ``StageWriter``), so recording
a stage reads no data file twice.

The state also holds what makes a rerun with nothing to do cheap:

- ``inputs``: every external input (a bag, a folder of logs) with its files' sha256, size
  and mtime, so an input is hashed again only when one of its files changed size or time
  (:class:`InputHashes`);
- ``plan``: the stages the config was planned into, with their validated options as plain
  JSON, under a fingerprint of the config, the run folder and the qsls sources
  (:mod:`qsls.pipeline.run.memo`), so an unchanged config is not validated again (which
  would import every stage's module);
- per stage, the package versions its key was made with (to say why it reruns) and its
  ``notes``: what the console prints about it (the verdict lines of an evaluation), recorded
  when the stage ran so that an up-to-date rerun reads no table.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from qsls.pipeline.core.artifacts import MANIFEST, atomic_write_bytes, sha256_file, sha256_path

STATE_FILE = "run_state.json"
STATE_VERSION = 3

FIRST_RUN = "not run yet"
"""Why a stage with no record runs (the console does not repeat it)."""


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FileStamp(_Frozen):
    """One file: its hash, and the size and mtime it had when recorded."""

    sha256: str
    size: int
    mtime_ns: int


class InputRecord(_Frozen):
    """One external input (file or folder): its :func:`sha256_path` and its files' stamps."""

    sha256: str
    files: dict[str, FileStamp] = Field(default_factory=dict)


class PlannedStage(_Frozen):
    """A stage of the plan: what its cache key is made of (options as plain JSON)."""

    id: str
    kind: str
    options: Any
    deps: list[str] = Field(default_factory=list)
    external: list[str] = Field(default_factory=list)


class Plan(_Frozen):
    """The stage graph a config was planned into, valid while ``fingerprint`` is unchanged."""

    fingerprint: str
    stages: list[PlannedStage]


class StageRecord(_Frozen):
    """A finished stage: its cache key and every file of its folder (relative paths)."""

    key: str
    files: dict[str, FileStamp] = Field(default_factory=dict)
    versions: dict[str, str] = Field(default_factory=dict)
    notes: dict[str, Any] = Field(default_factory=dict)

    @classmethod
    def of_folder(
        cls,
        key: str,
        folder: Path,
        versions: Mapping[str, str] | None = None,
        notes: Mapping[str, Any] | None = None,
    ) -> StageRecord:
        """Record ``folder`` now (hashes from its manifest where it lists them)."""
        folder = Path(folder)
        listed: dict[str, str] = {}
        if (folder / MANIFEST).is_file():
            listed = dict(json.loads((folder / MANIFEST).read_text()).get("files", {}))
        files = {}
        for f in sorted(p for p in folder.rglob("*") if p.is_file()):
            rel = f.relative_to(folder)
            if any(part.startswith(".") for part in rel.parts):
                continue
            st = os.stat(f)
            name = rel.as_posix()
            digest = listed.get(name) or sha256_file(f)
            files[name] = FileStamp(sha256=digest, size=st.st_size, mtime_ns=st.st_mtime_ns)
        return cls(key=key, files=files, versions=dict(versions or {}), notes=dict(notes or {}))

    def verify(self, folder: Path) -> tuple[str | None, StageRecord]:
        """(why ``folder`` no longer holds what was recorded or None, this record with the
        new mtimes of files that were hashed and found unchanged, so they are not hashed
        again next time)."""
        folder = Path(folder)
        if not self.files:
            return "nothing recorded", self
        touched: dict[str, FileStamp] = {}
        for name, stamp in self.files.items():
            f = folder / name
            try:
                st = os.stat(f)
            except FileNotFoundError:
                return f"{name} is missing", self
            if st.st_size == stamp.size and st.st_mtime_ns == stamp.mtime_ns:
                continue
            if st.st_size != stamp.size or sha256_file(f) != stamp.sha256:
                return f"{name} changed", self
            touched[name] = stamp.model_copy(update={"mtime_ns": st.st_mtime_ns})
        if not touched:
            return None, self
        return None, self.model_copy(update={"files": {**self.files, **touched}})


class InputHashes:
    """:func:`sha256_path` of external inputs, re-hashing only files whose size or mtime
    differ from ``known`` (the last run's :class:`InputRecord` s, by path).

    ``records`` are the inputs seen (to record in the state), ``hashed`` the files whose
    bytes were read.
    """

    def __init__(self, known: Mapping[str, InputRecord] | None = None) -> None:
        self.known = dict(known or {})
        self.records: dict[str, InputRecord] = {}
        self.hashed: list[Path] = []

    def digest(self, path: Path) -> str:
        name = str(path)
        if name in self.records:
            return self.records[name].sha256
        prev = self.known.get(name)
        stamps: dict[str, FileStamp] = {}

        def hash_file(f: Path) -> str:
            st = os.stat(f)
            old = prev.files.get(str(f)) if prev is not None else None
            if old is not None and (old.size, old.mtime_ns) == (st.st_size, st.st_mtime_ns):
                digest = old.sha256
            else:
                digest = sha256_file(f)
                self.hashed.append(Path(f))
            stamps[str(f)] = FileStamp(sha256=digest, size=st.st_size, mtime_ns=st.st_mtime_ns)
            return digest

        digest = sha256_path(path, hash_file)
        self.records[name] = InputRecord(sha256=digest, files=stamps)
        return digest


def _changed_versions(old: Mapping[str, str], new: Mapping[str, str]) -> str:
    diffs = [
        f"{k} {old.get(k, 'none')} -> {new.get(k, 'none')}"
        for k in sorted(set(old) | set(new))
        if old.get(k) != new.get(k)
    ]
    return ", ".join(diffs)


class RunState(_Frozen):
    """What ``qsls run`` finished, stage by stage (insertion order = run order)."""

    version: int = STATE_VERSION
    stages: dict[str, StageRecord] = Field(default_factory=dict)
    inputs: dict[str, InputRecord] = Field(default_factory=dict)
    plan: Plan | None = None

    @classmethod
    def load(cls, root: Path) -> RunState:
        """The state of run folder ``root``; empty when absent, unreadable or of an older
        version (every stage is then checked by running it again)."""
        p = Path(root) / STATE_FILE
        if not p.is_file():
            return cls()
        try:
            data = json.loads(p.read_bytes())
            if data.get("version") != STATE_VERSION:
                return cls()
            return cls.model_validate(data)
        except (ValueError, ValidationError, AttributeError, OSError):
            return cls()  # not JSON, not UTF-8 (a binary file), unreadable: run everything

    def save(self, root: Path) -> None:
        body = json.dumps(self.model_dump(mode="json"), indent=2, sort_keys=True) + "\n"
        atomic_write_bytes(Path(root) / STATE_FILE, body.encode())

    def with_stage(self, stage_id: str, record: StageRecord) -> RunState:
        return self.model_copy(update={"stages": {**self.stages, stage_id: record}})

    def without(self, stage_ids: set[str]) -> RunState:
        kept = {k: v for k, v in self.stages.items() if k not in stage_ids}
        return self.model_copy(update={"stages": kept})

    def with_inputs(self, inputs: Mapping[str, InputRecord]) -> RunState:
        return self.model_copy(update={"inputs": dict(inputs)})

    def with_plan(self, plan: Plan | None) -> RunState:
        return self.model_copy(update={"plan": plan})

    def check(
        self, stage_id: str, key: str, folder: Path, versions: Mapping[str, str] | None = None
    ) -> tuple[str | None, RunState]:
        """(why stage ``stage_id`` must run or None, this state with the stage's touched but
        unchanged files restamped)."""
        rec = self.stages.get(stage_id)
        if rec is None:
            return FIRST_RUN, self
        if rec.key != key:
            if versions is not None and rec.versions and rec.versions != dict(versions):
                why = f"package versions changed ({_changed_versions(rec.versions, versions)})"
                return why, self
            return "its options or inputs changed", self
        problem, checked = rec.verify(folder)
        if problem:
            return f"output {problem}", self
        return None, self if checked is rec else self.with_stage(stage_id, checked)
