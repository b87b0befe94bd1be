"""Deterministic file formats: the bytes of qsls's JSON, YAML, parquet, NPZ and image files,
and the atomic write of one file.

The same values give byte-identical files (sorted NPZ members with fixed timestamps, figures
without date or software metadata, one JSON writer with ``null`` for non-finite numbers,
docs/conventions.md#json); stage folders are written through
:class:`qsls.pipeline.core.artifacts.StageWriter`, which uses these.
"""

from __future__ import annotations

import io
import json
import math
import os
import shutil
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.locks import make_temporary


# --------------------------------------------------------------------------- plain values
def to_plain(obj: Any) -> Any:
    """Convert numpy scalars/arrays, paths, tuples and pydantic models to JSON/YAML types."""
    if hasattr(obj, "model_dump"):
        return to_plain(obj.model_dump(mode="json"))
    if isinstance(obj, Mapping):
        return {str(k): to_plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_plain(obj.tolist())
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, Path):
        return obj.as_posix()
    return obj


def canonical_json(obj: Any) -> str:
    return json.dumps(to_plain(obj), sort_keys=True, separators=(",", ":"), allow_nan=True)


# --------------------------------------------------------------------------- atomic files
def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same folder and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    folder = make_temporary(path)  # a signed temporary folder: the next writer may remove it
    tmp = folder / path.name
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def dump_yaml(obj: Any) -> str:
    import yaml

    return yaml.safe_dump(to_plain(obj), sort_keys=False, default_flow_style=None, width=100)


def load_yaml(text: str, source: str | Path = "") -> Any:
    """``yaml.safe_load`` through libyaml's parser where PyYAML was built with it (the same
    objects, 10 to 20 times faster: a flight loads its controller's certificate).

    A document whose aliases expand it beyond ``max(MAX_CONFIG_VALUES, len(text))`` values
    is refused (:class:`InputError` naming ``source``): without aliases a value takes at least
    one character, and qsls writes none, so only an alias "bomb" gets there (a 6 kB file
    that expands to billions: every reader that walks it, pydantic's included, never
    returns)."""
    import yaml

    # deferred: core.config builds pydantic's models; only its counting is needed here
    from qsls.pipeline.core.config import MAX_CONFIG_VALUES, expanded_size

    data = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    cap = max(MAX_CONFIG_VALUES, len(text))
    if isinstance(data, dict | list) and expanded_size(data, cap) > cap:
        raise InputError(
            f"{source or 'YAML document'}: expands to more than {cap} values through YAML "
            "aliases (qsls writes none); refused: regenerate the file or write the values out"
        )
    return data


def finite_or_null(obj: Any) -> Any:
    """``obj`` (plain values, :func:`to_plain`) with every NaN and infinity replaced by
    ``None``: JSON has no such numbers (``NaN``/``Infinity`` are Python's extension, which
    other readers refuse). A ``null`` in a number's place means "no finite value": not
    defined (a NaN), or unbounded where the field says so (docs/conventions.md#json)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [finite_or_null(v) for v in obj]
    return obj


def dump_json(obj: Any) -> str:
    """The one JSON writer of qsls's files: standard JSON (``allow_nan=False``), a non-finite
    number written as ``null`` (:func:`finite_or_null`)."""
    plain = finite_or_null(to_plain(obj))
    return json.dumps(plain, indent=2, sort_keys=False, allow_nan=False) + "\n"


def json_number(value: Any, null: float = math.nan) -> float:
    """A number read back from qsls's JSON: ``null`` is what the field's writer meant by it
    (``null``: NaN, "not defined", unless the field is unbounded where null, e.g. a
    calibration's ``lambda_hat``: ``math.inf``)."""
    return null if value is None else float(value)


def read_json(path: Path, fix: str = "") -> Any:
    """A JSON file qsls wrote, read whole: a missing, unreadable, truncated or corrupted file
    is one :class:`InputError` naming it (and ``fix``, what to do), never a traceback.
    ``NaN``/``Infinity`` written by older versions are still read."""
    path = Path(path)
    tail = f"; {fix}" if fix else ""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc}){tail}") from None
    try:
        return json.loads(raw)
    except (ValueError, RecursionError) as exc:  # not JSON, not UTF-8, truncated
        what = getattr(exc, "msg", None) or exc.__class__.__name__
        raise InputError(f"{path}: not valid JSON ({what}){tail}") from None


def parquet_bytes(df: Any) -> bytes:
    """Deterministic parquet bytes of a pandas DataFrame (no index) or a pyarrow Table (zstd,
    fixed writer)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = df if isinstance(df, pa.Table) else pa.Table.from_pandas(df, preserve_index=False)
    buf = io.BytesIO()
    pq.write_table(table, buf, compression="zstd", compression_level=3)
    return buf.getvalue()


def npz_bytes(arrays: Mapping[str, np.ndarray]) -> bytes:
    """Deterministic NPZ bytes: fixed member order and zip timestamps (np.savez stamps now)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(arrays):
            member = io.BytesIO()
            np.lib.format.write_array(member, np.asarray(arrays[name]), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, member.getvalue())
    return buf.getvalue()


def figure_bytes(fig: Any, fmt: str = "png", dpi: int = 110) -> bytes:
    """Deterministic image bytes of a matplotlib figure (no software/date metadata)."""
    import matplotlib

    buf = io.BytesIO()
    meta: dict[str, Any]
    if fmt == "png":
        meta = {"Software": None}
    elif fmt == "svg":
        matplotlib.rcParams["svg.hashsalt"] = "qsls"
        meta = {"Date": None, "Creator": None}
    else:
        meta = {"CreationDate": None, "Creator": None, "Producer": None}
    fig.savefig(buf, format=fmt, dpi=dpi, metadata=meta)
    return buf.getvalue()
