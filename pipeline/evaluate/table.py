"""The bound check's result, read and written here only: ``evaluation.parquet`` (one row per
flight and controller: the bounds, the errors, the premise and the verdict) and
``evaluation.json`` (the same rows with per-controller totals, the error model's numbers and
the warnings)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from qsls.pipeline.core.artifacts import StageWriter
from qsls.pipeline.core.errors import InputError

EVALUATION_FILE = "evaluation.parquet"
EVALUATION_JSON = "evaluation.json"


@dataclass(frozen=True)
class Evaluation:
    """An evaluate stage's table (``rows``) and its JSON document (``doc``)."""

    rows: pd.DataFrame = field(repr=False)
    doc: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def warnings(self) -> list[str]:
        return [str(w) for w in self.doc.get("warnings") or []]

    def save(self, w: StageWriter) -> None:
        """Both files inside an open stage writer (atomic with the stage)."""
        w.write_parquet(EVALUATION_FILE, self.rows)
        w.write_json(EVALUATION_JSON, self.doc)

    @staticmethod
    def exists(folder: Path) -> bool:
        return (Path(folder) / EVALUATION_FILE).is_file()

    @classmethod
    def load(cls, folder: Path) -> Evaluation:
        """Read an evaluate stage folder; one clear error when it holds no evaluation."""
        folder = Path(folder)
        f = folder / EVALUATION_FILE
        if not f.is_file():
            raise InputError(
                f"{folder}: no {EVALUATION_FILE}; pass a folder written by 'qsls evaluate'"
            )
        try:
            rows = pd.read_parquet(f)
        except Exception as exc:  # pyarrow raises several types for a corrupt file
            raise InputError(f"{f}: cannot read parquet ({exc.__class__.__name__})") from None
        doc: dict[str, Any] = {}
        j = folder / EVALUATION_JSON
        if j.is_file():
            try:
                loaded = json.loads(j.read_text())
            except json.JSONDecodeError as exc:
                raise InputError(f"{j}: not valid JSON ({exc.msg})") from None
            doc = loaded if isinstance(loaded, dict) else {}
        return cls(rows, doc)
