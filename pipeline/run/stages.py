"""The stages of ``qsls run``: a run config's resolved sections turned into a :class:`StageGraph`.

Folder layout under the run folder (one stage folder each, with its manifest)::

    simulate/<flight>/   (simulated flights only)
    ingest/<flight>/     flight.parquet
    fit/                 error_model.yaml (train flights)
    sweep/               sweep.parquet
    synth/<controller>/  controller.npz, certificate.yaml
    evaluate/            bound check on the held-out flights
    fly/                 the controllers flown (qsls fly)

Every stage's options are validated before anything runs, with the stage's own model: the
typed sections when the config is read (:func:`qsls.pipeline.run.runner.load_run_config`),
the flights' overlays, the paths and the sections laid under one another when it is
resolved (:func:`qsls.pipeline.run.sections.resolve_sections`). :func:`build_graph` only
builds stages from those options, and refuses what the asked-for stages cannot do.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from pathlib import Path
from typing import Any

from qsls.pipeline.calibrate.options import CalibrateOptions
from qsls.pipeline.control.options import SweepOptions, SweepSection, SynthOptions
from qsls.pipeline.core.artifacts import read_manifest
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.errormodel.options import FitOptions
from qsls.pipeline.evaluate.options import EvaluateOptions
from qsls.pipeline.fly.options import FlyOptions
from qsls.pipeline.ingest.options import IngestOptions
from qsls.pipeline.run.graph import Stage, StageGraph
from qsls.pipeline.run.sections import ResolvedFlight, Sections
from qsls.pipeline.sim.options import PERCEPTIONS, SimOptions

Execute = Callable[[Path, Mapping[str, Path]], Any]
"""A stage's ``execute(out, deps)`` (:class:`Stage`); it returns the stage's result."""
ALL_STAGES = ("simulate", "ingest", "fit", "sweep", "synth", "calibrate", "evaluate", "fly")
"""The stages a run config without ``stages:`` runs (and the report)."""


def build_graph(
    sec: Sections,
    stages: Collection[str] | None,
    root: Path,
    progress: Progress = NULL_PROGRESS,
) -> StageGraph:
    """The stages of ``sec`` (``stages``: those the config lists, ``None`` for all) with
    their dependencies, run folder ``root``."""
    wanted = set(stages or ALL_STAGES)
    listed = set(stages or ())
    graph = StageGraph(root)
    ingest_ids: dict[str, list[str]] = {"train": [], "heldout": []}
    sim_ids: dict[str, list[str | None]] = {"train": [], "heldout": []}
    by_id: dict[str, ResolvedFlight] = {}
    for fl in sec.flights:
        ingest_id, sim_id = _flight_stages(graph, fl, wanted, progress)
        ingest_ids[fl.role].append(ingest_id)
        sim_ids[fl.role].append(sim_id)
        by_id[ingest_id] = fl
    if "fit" not in wanted:
        return graph
    if not ingest_ids["train"]:
        raise ConfigError(
            f"{sec.source('flights')}: the fit needs at least one flight with role 'train'"
        )
    train = tuple(ingest_ids["train"])
    # simulated training flights logged their inputs: the disturbance is measured with them
    sims = [s for s in sim_ids["train"] if s is not None]
    logged = sims if len(sims) == len(train) and sec.fit.inputs is None else []
    execute = _fit_exec(sec.fit, list(train), logged, progress)
    graph.add(Stage("fit", "fit", sec.fit, execute, (*train, *logged), notes=_warnings))
    if sec.sweep is not None and "sweep" in wanted:
        _sweep_stage(graph, sec.sweep, progress)
    if "fly" in listed and sec.fly is None:
        raise ConfigError(
            f"{sec.source('stages')}: fly is listed but the config has no fly: section (the "
            "seeds, conditions and duration to fly): add one, or leave fly out"
        )
    if sec.synth is None or "synth" not in wanted:
        for stage in ("evaluate", "fly"):
            if stage in listed:
                raise ConfigError(
                    f"{sec.source('stages')}: {stage} is listed but there are no controllers to "
                    f"{stage}: add a synth: section (and synth to the stages)"
                )
        return graph
    graph.add(Stage("synth", "synth", sec.synth, _synth_exec(sec.synth, progress), deps=("fit",)))
    calibrated = None
    if sec.calibrate is not None and "calibrate" in wanted:
        calibrated = _calibrate_stage(graph, sec.calibrate, progress)
    heldout = ingest_ids["heldout"]
    if "evaluate" in wanted:
        if not heldout and ("evaluate" in listed or sec.evaluate is not None):
            where = sec.source("stages" if "evaluate" in listed else "evaluate")
            raise ConfigError(
                f"{where}: evaluate is asked for but there is nothing to evaluate: no flight "
                "has role 'heldout'; add a held-out flight, or leave evaluate out (the "
                "controllers fly in a fly: section)"
            )
        # a held-out flight is checked with the default options when the section is left out
        if heldout:
            _evaluate_stages(
                graph, sec.evaluate or EvaluateOptions(), heldout, progress, calibrated,
                [by_id[h].perception for h in heldout], [by_id[h].estimator for h in heldout],
            )  # fmt: skip
    if sec.fly is not None and "fly" in wanted:
        _fly_stage(graph, sec.fly, progress, calibrated)
    return graph


def _flight_stages(
    graph: StageGraph, fl: ResolvedFlight, wanted: Collection[str], progress: Progress
) -> tuple[str, str | None]:
    """The flight's simulate stage (simulated flights) and its ingest stage: their ids."""
    deps: tuple[str, ...] = ()
    if fl.sim is not None:
        if "simulate" not in wanted and not (graph.root / "simulate" / fl.name).is_dir():
            raise ConfigError(
                f"flight '{fl.name}' is simulated but the run's stages leave out simulate"
            )
        deps = (_simulate_stage(graph, fl.name, fl.sim, progress),)
    stage_id = f"ingest/{fl.name}"
    graph.add(
        Stage(
            stage_id,
            "ingest",
            {"options": fl.ingest, "sources": [s.name for s in fl.sources]},
            _ingest_exec(fl.ingest, list(fl.sources), deps, progress),
            deps=deps,
            external=fl.external,
            notes=_warnings,
        )
    )
    return stage_id, deps[0] if deps else None


def _sweep_stage(graph: StageGraph, sec: SweepSection, progress: Progress) -> None:
    opts = sec.options()
    execute = _sweep_exec(opts, sec.jobs, sec.scheduler, sec.wait_workers, progress)
    graph.add(Stage("sweep", "sweep", opts, execute, deps=("fit",)))


def _evaluate_stages(
    graph: StageGraph,
    eval_opts: EvaluateOptions,
    heldout: list[str],
    progress: Progress,
    calibrated: str | None,
    conditions: list[str],
    estimators: list[str],
) -> None:
    """The bound check on the held-out flights (``conditions``: their perception,
    ``estimators`` their estimator, ``''`` for a recorded flight); with a calibration
    (``calibrated``: its first condition), each calibrated controller is checked against its
    certificate for the flight's condition."""
    cal = ("calibrate",) if calibrated is not None else ()
    execute = _evaluate_exec(eval_opts, heldout, progress, calibrated, conditions, estimators)
    deps = ("fit", "synth", *cal, *heldout)
    graph.add(Stage("evaluate", "evaluate", eval_opts, execute, deps=deps, notes=_verdicts))


def _fly_stage(
    graph: StageGraph, opts: FlyOptions, progress: Progress, calibrated: str | None
) -> None:
    """The controllers flown (``fly:``, docs/evaluation.md), each checked against its own
    certificate (its condition's, with a calibration)."""
    cal = ("calibrate",) if calibrated is not None else ()
    execute = _fly_exec(opts, progress, calibrated)
    graph.add(Stage("fly", "fly", opts, execute, deps=("fit", "synth", *cal), notes=_verdicts))


def controller_folders(deps: Mapping[str, Path], calibrated: str | None) -> list[Path]:
    """The run's controllers: synth's, each replaced by its calibrated certificate's folder
    (``calibrate/<condition>/<name>``) where the calibration wrote one."""
    # deferred: a stage's code loads when it runs (a cached run loads none of it)
    from qsls.pipeline.evaluate.certified import expand_controllers

    if calibrated is None:
        return [deps["synth"]]
    folder = deps["calibrate"] / calibrated
    done = {p.name: p for p in expand_controllers([folder])} if folder.is_dir() else {}
    return [done.get(p.name, p) for p in expand_controllers([deps["synth"]])]


def condition_folders(deps: Mapping[str, Path]) -> dict[str, list[Path]]:
    """Per perception condition the calibration certified for, its calibrated certificates
    (``calibrate/<condition>/<name>``): the fly stage checks a flight against its own
    condition's (docs/calibration.md, "One certificate per condition")."""
    # deferred: a stage's code loads when it runs (a cached run loads none of it)
    from qsls.pipeline.evaluate.certified import expand_controllers

    root = deps["calibrate"]
    return {
        d.name: expand_controllers([d])
        for d in sorted(root.iterdir())
        if d.is_dir() and d.name in PERCEPTIONS
    }


def _calibrate_stage(graph: StageGraph, opts: CalibrateOptions, progress: Progress) -> str:
    """The candidates' calibration and validation flights (docs/calibration.md); its first
    condition (the one the evaluation checks a calibrated controller against)."""

    def execute(out: Path, deps: Mapping[str, Path]) -> Any:
        # deferred: a stage's code loads when it runs (a cached run loads none of it)
        from qsls.pipeline.calibrate.stage import calibrate

        return calibrate(deps["fit"], deps["synth"], opts, out, force=True, progress=progress)

    external = tuple(Path(p) for p in opts.recorded.paths)
    graph.add(
        Stage("calibrate", "calibrate", opts, execute, deps=("fit", "synth"), notes=_calibrated,
              external=external)
    )  # fmt: skip
    return str(opts.conditions[0])


def _warnings(out: Path) -> dict[str, Any]:
    """A stage's warnings (its manifest's results), kept in the run state for the console."""
    return {
        "warnings": [str(w) for w in read_manifest(out).get("results", {}).get("warnings") or []]
    }


def _calibrated(out: Path) -> dict[str, Any]:
    """One line per calibrated certificate, kept in the run state for the console."""
    # deferred: a stage's code loads when it runs (a cached run loads none of it)
    from qsls.pipeline.calibrate.summary import summary_lines

    return {"calibrated": summary_lines(out)}


def _verdicts(out: Path) -> dict[str, Any]:
    """An evaluation's verdict lines, one per controller, kept in the run state so that a
    rerun with nothing to do prints them without reading the table."""
    # deferred: a stage's code loads when it runs (a cached run loads none of it)
    from qsls.pipeline.evaluate.verdict import read_verdicts

    return {"verdicts": [line for v in read_verdicts(out) for line in v.lines()]}


def _simulate_stage(graph: StageGraph, name: str, opts: SimOptions, progress: Progress) -> str:
    """The flight's simulate stage: its id."""
    stage_id = f"simulate/{name}"

    def execute(out: Path, deps: Mapping[str, Path]) -> Any:
        # deferred: a stage's code loads when it runs (a cached run loads none of it)
        from qsls.pipeline.sim.simulate import simulate

        return simulate(opts, out, force=True, progress=progress)

    graph.add(Stage(stage_id, "simulate", opts, execute))
    return stage_id


def _ingest_exec(
    opts: IngestOptions, sources: list[Path], sim_deps: tuple[str, ...], progress: Progress
) -> Execute:
    def execute(out: Path, deps: Mapping[str, Path]) -> Any:
        # deferred: a stage's code loads when it runs (a cached run loads none of it)
        from qsls.pipeline.ingest.stage import ingest

        # a simulated flight's bag, by the name its simulate stage recorded
        srcs = [*sources, *(deps[d] / read_manifest(deps[d])["results"]["bag"] for d in sim_deps)]
        return ingest(srcs, opts, out, force=True, progress=progress)

    return execute


def _fit_exec(opts: FitOptions, train: list[str], logged: list[str], progress: Progress) -> Execute:
    def execute(out: Path, deps: Mapping[str, Path]) -> Any:
        # deferred: a stage's code loads when it runs (a cached run loads none of it)
        from qsls.pipeline.errormodel.fit import fit
        from qsls.pipeline.sim.simulate import CONTROL_FILE

        if logged:
            opts_ = opts.model_copy(
                update={"inputs": [str(deps[s] / CONTROL_FILE) for s in logged]}
            )
        else:
            opts_ = opts
        return fit([deps[d] for d in train], opts_, out, force=True, progress=progress)

    return execute


def _sweep_exec(
    opts: SweepOptions,
    jobs: int | None,
    scheduler: str | None,
    wait_workers: float,
    progress: Progress,
) -> Execute:
    def execute(out: Path, deps: Mapping[str, Path]) -> Any:
        # deferred: a stage's code loads when it runs (a cached run loads none of it)
        from qsls.pipeline.control.sweep import sweep

        return sweep(
            opts,
            out,
            error_model=deps["fit"],
            jobs=jobs,
            scheduler=scheduler,
            worker_timeout=wait_workers,
            force=True,
            progress=progress,
        )

    return execute


def _synth_exec(opts: SynthOptions, progress: Progress) -> Execute:
    def execute(out: Path, deps: Mapping[str, Path]) -> Any:
        # deferred: a stage's code loads when it runs (a cached run loads none of it)
        from qsls.pipeline.control.synth import synth

        return synth(deps["fit"], opts, out, force=True, progress=progress)

    return execute


def _evaluate_exec(
    opts: EvaluateOptions,
    heldout: list[str],
    progress: Progress,
    calibrated: str | None,
    conditions: list[str],
    estimators: list[str],
) -> Execute:
    def execute(out: Path, deps: Mapping[str, Path]) -> Any:
        # deferred: a stage's code loads when it runs (a cached run loads none of it)
        from qsls.pipeline.evaluate.stage import evaluate

        flights = [deps[d] for d in heldout]
        ctrls = controller_folders(deps, calibrated)
        return evaluate(
            flights, deps["fit"], ctrls, opts, out, force=True, progress=progress,
            conditions=conditions, estimators=estimators,
            by_condition=condition_folders(deps) if calibrated is not None else None,
        )  # fmt: skip

    return execute


def _fly_exec(opts: FlyOptions, progress: Progress, calibrated: str | None) -> Execute:
    def execute(out: Path, deps: Mapping[str, Path]) -> Any:
        # deferred: a stage's code loads when it runs (a cached run loads none of it)
        from qsls.pipeline.fly.stage import fly_evaluate

        ctrls = controller_folders(deps, calibrated)
        return fly_evaluate(
            deps["fit"], ctrls, opts, out, force=True, progress=progress,
            by_condition=condition_folders(deps) if calibrated is not None else None,
        )  # fmt: skip

    return execute
