"""Stage folders: atomic writes, ``manifest.json``, hashing, deterministic file formats.

Every stage writes through :class:`StageWriter`: files go into a hidden temporary folder
beside the output, ``manifest.json`` is written last, and the folder is renamed into place
only when the stage finished. An interrupted stage therefore leaves no half-written output
(at most a ``.NAME.tmp-PID`` folder, which the next writer removes once process ``PID`` is
gone), and an existing output is replaced only with ``force=True``.

Two guards hold whatever ``force`` says: an output folder that is, contains or lies inside
one of the stage's inputs is refused (resolved paths, symlinks followed), and an output
folder is written by one process at a time (:class:`FolderLock`, a ``.NAME.lock`` file
beside it; the kernel drops the lock of a dead process, so a stale lock is taken over).

Data files are deterministic (:mod:`qsls.pipeline.core.formats`): the same inputs and options
give byte-identical parquet, YAML, JSON, NPZ and PNG files. Only ``manifest.json`` records the wall time.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from qsls.pipeline import __version__
from qsls.pipeline.core.errors import InputError, OutputExistsError

# the file formats (core/formats.py); the "x as x" ones are re-exported for the stages
# that import them from here with the writer
from qsls.pipeline.core.formats import atomic_write_bytes as atomic_write_bytes
from qsls.pipeline.core.formats import (
    canonical_json,
    dump_json,
    dump_yaml,
    figure_bytes,
    parquet_bytes,
    to_plain,
)
from qsls.pipeline.core.formats import finite_or_null as finite_or_null
from qsls.pipeline.core.formats import json_number as json_number
from qsls.pipeline.core.formats import load_yaml as load_yaml
from qsls.pipeline.core.formats import npz_bytes as npz_bytes
from qsls.pipeline.core.formats import read_json as read_json
from qsls.pipeline.core.locks import (  # clean_stale: re-exported for the report stage
    OLD_MARK,
    TEMP_MARKER,
    TMP_MARK,
    check_unlocked,
    check_writable,
    clean_stale,
    hold_output,
    is_temporary,
    make_parent,
    make_temporary,
    mark_temporary,
    release_output,
    temporary_name,
)

MANIFEST = "manifest.json"
_TMP_MARK = TMP_MARK
_OLD_MARK = OLD_MARK

# Packages whose versions go into every manifest (the ones that shape the numbers).
_PACKAGES = (
    "numpy",
    "scipy",
    "pandas",
    "pyarrow",
    "cvxpy",
    "clarabel",
    "rosbags",
    "mcap",
    "rotorpy",
    "matplotlib",
    "pydantic",
)


# --------------------------------------------------------------------------- hashing
_PRIMED: dict[tuple[str, int, int], str] = {}


def _file_key(path: Path) -> tuple[str, int, int]:
    st = os.stat(path)
    return (os.path.realpath(path), st.st_size, st.st_mtime_ns)


def _hash_file(path: Path) -> str:
    # file_digest reads into one reused buffer: no fresh 1 MiB object per read
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def sha256_file(path: Path) -> str:
    """Hex sha256 of one file's bytes (a hash primed by :func:`prime_hashes` is used once)."""
    primed = _PRIMED.pop(_file_key(path), None) if _PRIMED else None
    return primed if primed is not None else _hash_file(path)


def prime_hashes(paths: Iterable[Path]) -> None:
    """Hash the files (and folders' files) of ``paths`` now, for the next :func:`sha256_file`.

    A stage can run this in a background thread while it reads big inputs, so that
    StageWriter finds their hashes ready. Each primed hash is used once, and only while the
    file keeps its size and modification time.
    """
    for p in paths:
        p = Path(p)
        files = [p] if p.is_file() else sorted(f for f in p.rglob("*") if f.is_file())
        for f in files:
            key = _file_key(f)
            _PRIMED[key] = _hash_file(f)


def sha256_path(path: Path, hash_file: Callable[[Path], str] | None = None) -> str:
    """Hex sha256 of a file, or of a folder: its files' relative paths and hashes, sorted.

    A folder's ``manifest.json`` is left out: it holds the wall time, which changes on
    every run although the data does not. ``hash_file`` hashes one file (default
    :func:`sha256_file`; the run cache passes one that reuses hashes of unchanged files).
    """
    path = Path(path)
    hash_file = hash_file or sha256_file
    if path.is_file():
        return hash_file(path)
    if not path.is_dir():
        raise InputError(f"{path}: no such file or folder")
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        rel = f.relative_to(path).as_posix()
        if rel == MANIFEST or any(part.startswith(".") for part in f.relative_to(path).parts):
            continue
        h.update(rel.encode() + b"\0" + hash_file(f).encode() + b"\n")
    return h.hexdigest()


def sha256_json(obj: Any) -> str:
    """Hex sha256 of an object's canonical JSON (sorted keys): the hash of a set of options."""
    return hashlib.sha256(canonical_json(obj).encode()).hexdigest()


# --------------------------------------------------------------------------- manifests
def package_versions() -> dict[str, str]:
    """``{package: version}`` of the packages a manifest records, and Python's.

    The value of ``importlib.metadata.version(name)``, read from the metadata's header only:
    ``version`` parses the whole file as an email, long description included (numpy's and
    pandas' run to tens of kB), which was ~12 ms of every stage's start."""
    import email
    from importlib.metadata import PackageNotFoundError, distribution

    out = {}
    for name in _PACKAGES:
        try:
            dist = distribution(name)
        except PackageNotFoundError:
            out[name] = "not installed"
            continue
        # Distribution.metadata's sources, in its order; the header ends at the first blank line
        text = dist.read_text("METADATA") or dist.read_text("PKG-INFO") or dist.read_text("")
        out[name] = email.message_from_string((text or "").partition("\n\n")[0])["Version"]
    import platform

    out["python"] = platform.python_version()
    return out


def describe_inputs(inputs: Iterable[Path]) -> list[dict[str, Any]]:
    """``[{path, sha256, bytes}]`` for every input file or folder, in the order given."""
    out = []
    for p in inputs:
        p = Path(p)
        size = (
            p.stat().st_size
            if p.is_file()
            else sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
        )
        out.append({"path": p.as_posix(), "sha256": sha256_path(p), "bytes": int(size)})
    return out


def read_manifest(folder: Path) -> dict[str, Any]:
    """The manifest of a stage folder; a clear error when the folder is not one."""
    path = Path(folder) / MANIFEST
    if not path.is_file():
        raise InputError(
            f"{folder}: not a qsls stage folder (no {MANIFEST}); "
            "pass a folder written by a qsls command"
        )
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: manifest is not valid JSON ({exc.msg})") from None


def require_stage(folder: Path, stage: str) -> dict[str, Any]:
    """Read a folder's manifest and check it was written by ``stage``."""
    manifest = read_manifest(folder)
    if manifest.get("stage") != stage:
        raise InputError(
            f"{folder}: written by stage '{manifest.get('stage')}', expected a '{stage}' folder"
        )
    return manifest


def read_stage_json(folder: Path, name: str, fix: str) -> Any:
    """The JSON file ``name`` of a stage folder, as its stage wrote it: refused in one line
    (:class:`InputError`, with ``fix``) when its bytes are not those its ``manifest.json``
    lists (edited or corrupted since, whatever its size and time say: a cache that trusts
    them would not see it), or when it is not JSON (:func:`read_json`)."""
    check_stage_file(folder, name, fix)
    return read_json(Path(folder) / name, fix)


def check_stage_file(folder: Path, name: str, fix: str) -> None:
    """Refuse (one :class:`InputError` line, with ``fix``) the file ``name`` of a stage
    folder when its bytes are not those the folder's ``manifest.json`` lists: corrupted or
    edited since its stage wrote it. A folder without a manifest, or a file it does not list,
    is not checked (files written by hand or by an older version)."""
    path = Path(folder) / name
    if not (Path(folder) / MANIFEST).is_file() or not path.is_file():
        return
    listed = (read_manifest(folder).get("files") or {}).get(name)
    if listed is not None and _hash_file(path) != listed:
        raise InputError(
            f"{path}: changed since its stage wrote it (its sha256 is not the one its "
            f"{MANIFEST} lists); {fix}"
        )


# --------------------------------------------------------------------------- stage writer
@dataclass
class StageWriter:
    """Write one stage's output folder atomically.

    Use as a context manager::

        with StageWriter(out, "ingest", options=cfg, inputs=[bag], force=force) as w:
            w.write_parquet(FLIGHT_FILE, df)
            w.results["time_offset_s"] = offset

    On success the folder appears at ``out`` with ``manifest.json``; on any exception the
    temporary folder is removed and ``out`` is untouched.
    """

    out: Path
    stage: str
    options: Any = None
    inputs: Sequence[Path] = ()
    force: bool = False
    results: dict[str, Any] = field(default_factory=dict)
    tmp: Path = field(init=False)
    _t0: float = field(init=False, default=0.0)

    def __post_init__(self) -> None:
        self.out = Path(self.out)

    def __enter__(self) -> StageWriter:
        check_output(self.out, self.force, self.inputs)
        self._t0 = time.perf_counter()
        make_parent(self.out, "output folder")
        hold_output(self.out)
        clean_stale(self.out)
        self.tmp = make_temporary(self.out)
        self._inputs = describe_inputs(self.inputs)
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        try:
            if exc_type is None:
                self._write_manifest()
                publish(self.tmp, self.out)
        finally:
            shutil.rmtree(self.tmp, ignore_errors=True)
            release_output(self.out)

    # ---- files
    def path(self, name: str) -> Path:
        """Path of ``name`` inside the temporary folder (for writers that need a path)."""
        p = self.tmp / name
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def write_bytes(self, name: str, data: bytes) -> Path:
        p = self.path(name)
        p.write_bytes(data)
        return p

    def write_text(self, name: str, text: str) -> Path:
        return self.write_bytes(name, text.encode())

    def write_parquet(self, name: str, df: Any) -> Path:
        return self.write_bytes(name, parquet_bytes(df))

    def write_yaml(self, name: str, obj: Any) -> Path:
        return self.write_text(name, dump_yaml(obj))

    def write_json(self, name: str, obj: Any) -> Path:
        return self.write_text(name, dump_json(obj))

    def write_figure(self, name: str, fig: Any, dpi: int = 110) -> Path:
        import matplotlib.pyplot as plt

        fmt = Path(name).suffix.lstrip(".") or "png"
        try:
            return self.write_bytes(name, figure_bytes(fig, fmt, dpi))
        finally:
            plt.close(fig)

    # ---- manifest
    def _write_manifest(self) -> None:
        options = to_plain(self.options) if self.options is not None else {}
        manifest = {
            "stage": self.stage,
            "qsls_version": __version__,
            "inputs": self._inputs,
            "options": options,
            "input_hash": sha256_json({"inputs": self._inputs, "options": options}),
            "results": to_plain(self.results),
            "files": {
                f.relative_to(self.tmp).as_posix(): sha256_file(f)
                for f in sorted(self.tmp.rglob("*"))
                if f.is_file() and f.name != TEMP_MARKER  # gone once published
            },
            "packages": package_versions(),
            "wall_time_s": round(time.perf_counter() - self._t0, 3),
        }
        (self.tmp / MANIFEST).write_text(dump_json(manifest))


def check_output(
    out: Path, force: bool, inputs: Iterable[Path] = (), known: Sequence[str] = ()
) -> None:
    """Refuse an output folder that overlaps an input, cannot be written (a read-only or
    missing location, :func:`check_writable`), is being written by another process (its
    lock, :func:`check_unlocked`; :class:`StageWriter` holds it while it writes), or exists
    (unless ``force``). ``--force`` replaces only a folder qsls wrote: one holding files its
    ``manifest.json`` does not list (the user's notes) is refused, never deleted
    (:func:`foreign_files`; ``known``: name patterns taken as qsls's in a folder without a
    manifest, as older reports had)."""
    out = Path(out)
    refuse_in_use(out)
    refuse_overlap(out, inputs)
    check_writable(out, "output folder")
    check_unlocked(out)
    if out.exists() and not force:
        raise OutputExistsError(f"{out} already exists; pass --force to overwrite it")
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder; choose another --out")
    foreign = foreign_files(out, known) if out.exists() else []
    if foreign:
        shown = ", ".join(foreign[:3]) + (
            f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
        )
        raise OutputExistsError(
            f"{out} holds files qsls did not write ({shown}); --force replaces only a folder "
            "a qsls command wrote: move them away or choose another --out"
        )


def refuse_in_use(out: Path, what: str = "output folder") -> None:
    """Refuse an output that names no folder of its own: ``.``, ``..``, ``/`` and anything
    that resolves to the filesystem's root, the home folder, the current folder or a folder
    holding it. A stage replaces its output folder as a whole, so such an output would take
    the user's files (and the process's own working folder) with it."""
    given = Path(out)
    o = given.resolve()
    cwd = Path.cwd().resolve()
    named = given.name not in ("", ".", "..")
    why = None
    if o == o.parent:
        why = "is the filesystem's root"
    elif o == Path.home().resolve():
        why = "is your home folder"
    elif o == cwd:
        why = "is the current folder"
    elif o in cwd.parents:
        why = f"holds the current folder ({cwd})"
    elif not named:
        why = f"names no folder of its own ({o})"
    if why is not None:
        raise InputError(
            f"{what} {given} {why}; name a new folder for the output, e.g. --out "
            f"{'./' if o == cwd else ''}results"
        )


def foreign_files(folder: Path, known: Sequence[str] = ()) -> list[str]:
    """The files of ``folder`` (relative paths) that its ``manifest.json`` does not list:
    what ``--force`` would delete that qsls did not write. Without a readable manifest every
    file is foreign, unless its name matches a pattern of ``known``."""
    import fnmatch

    folder = Path(folder)
    listed: set[str] = {MANIFEST, TEMP_MARKER}  # the marker: a publish killed half-way
    try:
        files = json.loads((folder / MANIFEST).read_bytes()).get("files", {})
        listed |= set(files) if isinstance(files, dict) else set()
        patterns: Sequence[str] = ()
    except (OSError, ValueError, AttributeError):
        patterns = known
    out = []
    for f in sorted(folder.rglob("*")):
        if f.is_dir() and not f.is_symlink():
            continue
        rel = f.relative_to(folder).as_posix()
        if rel in listed or any(fnmatch.fnmatchcase(rel, p) for p in patterns):
            continue
        out.append(rel)
    return out


def refuse_overlap(
    out: Path, inputs: Iterable[Path], what: str = "output folder", *, contains: bool = True
) -> None:
    """An output (``what``: folder or file) that is, contains or lies inside an input would
    destroy it on publish: refused with one line, whatever ``--force`` says (resolved,
    symlinks followed). The ``--config`` files the command read are inputs too.
    ``contains=False`` allows an output folder holding an input (a run folder, which is
    never replaced as a whole)."""
    # deferred: core.config builds the option models (~25 ms), which commands that only
    # read stage folders (qsls run --help, through run.state) need not
    from qsls.pipeline.core.config import config_files

    o = Path(out).resolve()
    for given in [*inputs, *config_files()]:
        i = Path(given).resolve()
        if o == i:
            how = "is"
        elif o in i.parents and contains:
            how = "contains"
        elif i in o.parents:
            how = "lies inside"
        else:
            continue
        raise InputError(
            f"{what} {out} {how} the input {given}; writing it would destroy the input "
            f"(even with --force): choose an {what} apart from the inputs"
        )


def publish(tmp: Path, out: Path) -> None:
    """Move a finished temporary folder to ``out``, replacing an old one by renames only."""
    old = None
    if out.is_symlink():  # --force onto a link: the link is replaced, its target left alone
        old = temporary_name(out, _OLD_MARK)
        os.replace(out, old)
        os.replace(tmp, out)
        (out / TEMP_MARKER).unlink(missing_ok=True)
        old.unlink()
        return
    if out.exists():
        old = temporary_name(out, _OLD_MARK)
        if old.exists() or old.is_symlink():
            if not is_temporary(old):
                raise OutputExistsError(
                    f"{old} is in the way and was not written by qsls; move it away and retry"
                )
            shutil.rmtree(old)
        os.replace(out, old)
        with contextlib.suppress(OSError):  # signed, so a run killed before the rmtree
            mark_temporary(old)  # below has it removed (a full disk: it stays unsigned)
    os.replace(tmp, out)
    (out / TEMP_MARKER).unlink(missing_ok=True)  # a finished folder, no longer a temporary
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
