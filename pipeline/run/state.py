"""The run state (``RUN_DIR/run_state.json``): per stage, its cache key and its outputs.

A stage is up to date when its recorded key equals its current key *and* its folder still
holds the files it wrote: every recorded file exists with its recorded sha256. The check is
cheap: a file whose size and modification time are the recorded ones is taken as unchanged;
only a file whose size or time differs is hashed (a ``touch`` costs one hash, not a rerun).
The hashes come from the stage's ``manifest.json`` (written by ``StageWriter``), so recording
a stage reads no data file twice.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from qsls.pipeline.core.artifacts import MANIFEST, atomic_write_bytes, sha256_file

STATE_FILE = "run_state.json"
STATE_VERSION = 2


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FileStamp(_Frozen):
    """One output file: its hash, and the size and mtime it had when recorded."""

    sha256: str
    size: int
    mtime_ns: int


class StageRecord(_Frozen):
    """A finished stage: its cache key and every file of its folder (relative paths)."""

    key: str
    files: dict[str, FileStamp] = Field(default_factory=dict)

    @classmethod
    def of_folder(cls, key: str, folder: Path) -> StageRecord:
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
        return cls(key=key, files=files)

    def problem(self, folder: Path) -> str | None:
        """Why ``folder`` no longer holds what was recorded (None when it does)."""
        folder = Path(folder)
        if not self.files:
            return "nothing recorded"
        for name, stamp in self.files.items():
            f = folder / name
            try:
                st = os.stat(f)
            except FileNotFoundError:
                return f"{name} is missing"
            if st.st_size == stamp.size and st.st_mtime_ns == stamp.mtime_ns:
                continue
            if st.st_size != stamp.size or sha256_file(f) != stamp.sha256:
                return f"{name} changed"
        return None


class RunState(_Frozen):
    """What ``qsls run`` finished, stage by stage (insertion order = run order)."""

    version: int = STATE_VERSION
    stages: dict[str, StageRecord] = Field(default_factory=dict)

    @classmethod
    def load(cls, root: Path) -> RunState:
        """The state of run folder ``root``; empty when absent, unreadable or of an older
        version (every stage is then checked by running it again)."""
        p = Path(root) / STATE_FILE
        if not p.is_file():
            return cls()
        try:
            data = json.loads(p.read_text())
            if data.get("version") != STATE_VERSION:
                return cls()
            return cls.model_validate(data)
        except (json.JSONDecodeError, ValidationError, AttributeError):
            return cls()

    def save(self, root: Path) -> None:
        body = json.dumps(self.model_dump(mode="json"), indent=2, sort_keys=True) + "\n"
        atomic_write_bytes(Path(root) / STATE_FILE, body.encode())

    def with_stage(self, stage_id: str, record: StageRecord) -> RunState:
        return RunState(stages={**self.stages, stage_id: record})

    def without(self, stage_ids: set[str]) -> RunState:
        return RunState(stages={k: v for k, v in self.stages.items() if k not in stage_ids})

    def why_stale(self, stage_id: str, key: str, folder: Path) -> str | None:
        """Why stage ``stage_id`` must run (None when it is up to date)."""
        rec = self.stages.get(stage_id)
        if rec is None:
            return "not run yet"
        if rec.key != key:
            return "its options or inputs changed"
        problem = rec.problem(folder)
        return f"output {problem}" if problem else None
