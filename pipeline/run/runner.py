"""``qsls run CONFIG``: the whole pipeline from one YAML file.

A run config names flights (simulated, or real logs to ingest) and the options of every
stage. :func:`plan` turns it into a :class:`StageGraph`::

    simulate/<flight>  ->  ingest/<flight>  ->  fit  ->  sweep
                                                     ->  synth  ->  evaluate  ->  report

and :func:`run` executes it under ``RUN_DIR`` (default ``runs/<name>``), skipping every
stage whose options and inputs did not change (see :mod:`qsls.pipeline.run.graph`).
Relative paths in the config are relative to the config file's folder.
"""

from __future__ import annotations

import os
import subprocess
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from qsls.pipeline import __version__
from qsls.pipeline.control.options import ProblemOptions
from qsls.pipeline.core.artifacts import (
    atomic_write_bytes,
    dump_json,
    refuse_overlap,
    sha256_file,
)
from qsls.pipeline.core.config import SHARED, read_yaml, validate, with_shared
from qsls.pipeline.core.errors import ConfigError, QslsError
from qsls.pipeline.core.locks import (
    FolderLock,
    check_writable,
    clean_dead_temporaries,
    unwritable,
)
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.report.stage import REPORT_DIR, RUN_FILE, report
from qsls.pipeline.run.graph import Stage, StageGraph, StageOutcome, run_versions
from qsls.pipeline.run.memo import fingerprint, planned_graph
from qsls.pipeline.run.paths import resolve_path
from qsls.pipeline.run.runconfig import MODELS, SECTIONS, RunConfig
from qsls.pipeline.run.runconfig import FlightSpec as FlightSpec
from qsls.pipeline.run.sections import resolve_sections
from qsls.pipeline.run.stages import build_graph
from qsls.pipeline.run.state import STATE_FILE

# (stage id, "running" | "ran" | "skipped", index, count, why it ran)
OnStage = Callable[[str, str, int, int, str], None]
STAGE_ORDER = ("simulate", "ingest", "fit", "sweep", "synth", "calibrate", "evaluate", "report")


@dataclass(frozen=True)
class RunResult:
    root: Path
    outcomes: tuple[StageOutcome, ...]
    report: Path | None

    def summary(self) -> dict[str, Any]:
        ran = [o.id for o in self.outcomes if o.status == "ran"]
        skipped = [o.id for o in self.outcomes if o.status == "skipped"]
        out = {
            "run folder": str(self.root),
            "stages run": len(ran),
            "stages up to date (skipped)": len(skipped),
        }
        if self.report is not None:
            out["report"] = str(self.report / "index.html")
        return out


def load_run_config(path: Path) -> RunConfig:
    """A run config, every typed section validated by its stage's model; an error names the
    section (``CONFIG_FOLDER: sweep: unknown option 'jbos'; did you mean 'jobs'?``), as the
    stage command's ``--config`` does."""
    raw = read_yaml(path)
    base = Path(path).resolve().parent
    if isinstance(raw.get(SHARED), Mapping):  # its own errors name it, before it is laid under
        validate(ProblemOptions, raw[SHARED], f"{base}: {SHARED}")
    raw = with_shared(raw, f"{base}")
    typed = dict(raw)
    for key, model in MODELS.items():
        if isinstance(raw.get(key), Mapping):
            typed[key] = validate(model, raw[key], f"{base}: {key}")
    cfg = validate(RunConfig, typed, str(path))
    cfg._given = {k: raw[k] for k in SECTIONS if k in raw}
    return cfg


def _git_commit() -> str:
    src = Path(__file__).resolve().parent
    try:
        out = subprocess.run(
            ["git", "-C", str(src), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10
        )
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"
    return out.stdout.strip() if out.returncode == 0 else "unknown"


def plan(
    cfg: RunConfig, config_path: Path, root: Path, progress: Progress = NULL_PROGRESS
) -> StageGraph:
    """The stage graph of a run config: its sections resolved into each stage's options
    (validated here, before anything runs), then the stages built from them."""
    sections = resolve_sections(cfg, Path(config_path).resolve().parent)
    return build_graph(sections, cfg.stages, root, progress)


def run(
    config_path: Path,
    *,
    out: Path | None = None,
    force: bool = False,
    from_stage: str | None = None,
    progress: Progress = NULL_PROGRESS,
    on_stage: OnStage | None = None,
) -> RunResult:
    """Run the stages a config names, in order, caching each by the hash of its inputs."""
    config_path = Path(config_path)
    cfg = load_run_config(config_path)
    root = Path(out) if out is not None else resolve_path(Path.cwd(), cfg.out or f"runs/{cfg.name}")
    if from_stage is not None and from_stage not in (*STAGE_ORDER, "fly"):
        raise ConfigError(
            f"--from {from_stage}: not a stage (choose from {', '.join(STAGE_ORDER)}, fly)"
        )
    if root.name in ("", ".", ".."):  # --out . / --out ..: the folder's own name
        root = Path(os.path.abspath(root))
    check_run_root(root)
    check_writable(root, "run folder")
    # options checked before anything is written; an unchanged config is not planned again
    versions = run_versions()
    fp = fingerprint(cfg, config_path.parent, root, versions)
    graph = planned_graph(root, fp, lambda: plan(cfg, config_path, root, progress), versions)
    refuse_run_overlap(root, graph)
    check_foreign_folder(root)
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise unwritable(root, exc, "run folder") from None
    with FolderLock(root, "run folder"):
        # the levels a run writes: the run folder and the parents of its stage folders
        clean_dead_temporaries([root, *(graph.out(s).parent for s in graph.stages)])
        return _run_locked(cfg, config_path, root, graph, force, from_stage, on_stage)


def check_run_root(root: Path) -> None:
    """Refuse a filesystem root or a file as the run folder (before anything is read)."""
    resolved = Path(root).resolve()
    if resolved == resolved.parent:
        raise ConfigError(
            f"run folder {root}: a filesystem root cannot be a run folder; "
            "pass --out with a folder of its own (e.g. --out runs/NAME)"
        )
    if resolved.exists() and not resolved.is_dir():
        raise ConfigError(
            f"run folder {root} exists and is not a folder; pass --out with a folder of its own"
        )

    for name in (RUN_FILE, STATE_FILE):
        own = Path(root) / name
        if own.is_symlink() or (own.exists() and not own.is_file()):
            raise ConfigError(
                f"{own} is not a file qsls wrote (a folder or a link); move it away and run again"
            )


def check_foreign_folder(root: Path) -> None:
    """Refuse an existing folder that holds files and is not a run folder (no run.json nor
    run_state.json): a run writes stage folders (``fit``, ``report``, ...) into it and
    would replace the user's own (``--out .``, ``--out ..``, a project folder)."""
    root = Path(root)
    if not root.is_dir() or (root / RUN_FILE).exists() or (root / STATE_FILE).exists():
        return
    if next(iter(os.scandir(root)), None) is not None:
        raise ConfigError(
            f"run folder {root} holds files and is not a qsls run folder (no {RUN_FILE}); "
            "pass --out with a new or empty folder (e.g. --out runs/NAME)"
        )


def refuse_run_overlap(root: Path, graph: StageGraph) -> None:
    """Refuse, before anything is written, a run folder that is or lies inside an input
    (a bag folder, a log file; symlinks followed) or whose stage folders would overlap one."""
    inputs = [p for s in graph.stages for p in s.external]
    refuse_overlap(root, inputs, "run folder", contains=False)
    for s in graph.stages:
        refuse_overlap(graph.out(s), inputs, "stage folder")


def run_info(cfg: RunConfig, config_path: Path, stage_ids: list[str]) -> dict[str, Any]:
    """What ``run.json`` records. The config by its resolved absolute path: the same file
    named relatively, absolutely or from another working directory gives the same record,
    so a run with nothing to do leaves ``run.json`` and the report as they are."""
    return {
        "name": cfg.name,
        "seed": cfg.seed,
        "qsls_version": __version__,
        "git_commit": _git_commit(),
        "config_path": Path(config_path).resolve().as_posix(),
        "config_sha256": sha256_file(config_path),
        "config": cfg.record(),
        "stages": list(stage_ids),
    }


def _run_locked(
    cfg: RunConfig,
    config_path: Path,
    root: Path,
    graph: StageGraph,
    force: bool,
    from_stage: str | None,
    on_stage: OnStage | None,
) -> RunResult:
    info = run_info(cfg, config_path, graph.ids)
    body = dump_json(info).encode()
    if not (root / RUN_FILE).is_file() or (root / RUN_FILE).read_bytes() != body:
        atomic_write_bytes(root / RUN_FILE, body)

    def started(stage: Stage, i: int, n: int) -> None:
        if on_stage:
            on_stage(stage.id, "running", i, n, "")

    def done(oc: StageOutcome, i: int, n: int) -> None:
        if on_stage:
            on_stage(oc.id, oc.status, i, n, oc.reason)

    # the report runs after every stage (not counted among them): when one ran, when its
    # folder or run.json changed, or when asked (--force, --from report, which reruns only it)
    from_kind = None if from_stage == "report" else from_stage
    wanted = set(cfg.stages or STAGE_ORDER)
    try:
        outcomes = graph.run(force=force, from_kind=from_kind, on_start=started, on_done=done)
    except QslsError as exc:
        if cfg.report and "report" in wanted:
            _partial_report(root, exc)
        raise
    report_dir = None
    if cfg.report and "report" in wanted:
        report_dir = root / REPORT_DIR  # inside the run: a run writes only where it was told
        n = len(outcomes)

        def report_started(stage: Stage) -> None:
            if on_stage:
                on_stage("report", "running", n, n + 1, "")

        redo = "--force" if force else ("--from report" if from_stage == "report" else None)
        stage = _report_stage(root, report_dir, info, tuple(graph.ids))
        graph.run_last(stage, outcomes, redo=redo, on_start=report_started)
    return RunResult(root=root, outcomes=tuple(outcomes), report=report_dir)


def _partial_report(root: Path, exc: QslsError) -> None:
    """After a stage failed: the report of the stages that finished (when there are some),
    its place added to the error's one line. A report that cannot be made adds nothing."""
    try:
        done = report(root, root / REPORT_DIR, force=True)
    except QslsError:
        return
    exc.args = (
        f"{exc}; the report of the stages that finished: {done.out / 'index.html'}",
        *exc.args[1:],
    )


def _report_stage(root: Path, out: Path, info: dict[str, Any], deps: tuple[str, ...]) -> Stage:
    """The report of run folder ``root`` into ``out``: it reads the stage folders and run.json."""

    def execute(folder: Path, deps: Any) -> Any:
        return report(root, folder, force=True)

    options = {"out": str(out.resolve()), "run": info}
    return Stage("report", "report", options, execute, deps=deps, folder=out)
