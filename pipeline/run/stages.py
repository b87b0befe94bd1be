"""The stages of ``qsls run``: a run config turned into a :class:`StageGraph`.

Folder layout under the run folder (one stage folder each, with its manifest)::

    simulate/<flight>/   (simulated flights only)
    ingest/<flight>/     flight.parquet
    fit/                 error_model.yaml (train flights)
    sweep/               sweep.parquet
    synth/<controller>/  controller.npz, certificate.yaml
    evaluate/            bound check on the held-out flights
    fly/                 the controllers flown (qsls fly)

Every stage's options are validated before anything runs, with the stage's own model, so a
misspelled option is reported with the config's section and the nearest valid name: the typed
sections when the config is read (:func:`qsls.pipeline.run.runner.load_run_config`), a
flight's simulate and ingest options (the flight's own laid over the run's section as it was
written) and the flying options (the ``fly:`` section over the run's ``simulate:``) here.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from pathlib import Path
from typing import Any

from qsls.pipeline.calibrate.options import CalibrateOptions
from qsls.pipeline.control.options import SweepOptions, SweepSection, SynthOptions
from qsls.pipeline.core.artifacts import read_manifest
from qsls.pipeline.core.config import merge, validate
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.errormodel.options import FitOptions
from qsls.pipeline.evaluate.options import EvaluateOptions
from qsls.pipeline.evaluate.section import EvaluateSection
from qsls.pipeline.fly.options import FlyOptions, flying
from qsls.pipeline.ingest.options import IngestOptions
from qsls.pipeline.run.graph import Stage, StageGraph
from qsls.pipeline.run.paths import missing_hint, resolve_path
from qsls.pipeline.run.runconfig import FlightSpec, RunConfig
from qsls.pipeline.sim.options import PERCEPTIONS, SimOptions

Src = Callable[[str], str]
Execute = Callable[[Path, Mapping[str, Path]], Any]
"""A stage's ``execute(out, deps)`` (:class:`Stage`); it returns the stage's result."""


def build_graph(
    cfg: RunConfig, base: Path, root: Path, progress: Progress = NULL_PROGRESS
) -> StageGraph:
    """Stages for ``cfg``; paths relative to ``base``."""
    wanted = set(
        cfg.stages
        or ("simulate", "ingest", "fit", "sweep", "synth", "calibrate", "evaluate", "fly")
    )
    graph = StageGraph(root)

    def src(section: str) -> str:
        return f"{base}: {section}"

    if not cfg.flights:
        raise ConfigError(f"{src('flights')}: a run needs at least one flight")
    ingest_ids: dict[str, list[str]] = {"train": [], "heldout": []}
    sim_ids: dict[str, list[str | None]] = {"train": [], "heldout": []}
    perception: dict[str, str] = {}  # a simulated flight's condition ('' for a recorded one)
    estimator: dict[str, str] = {}  # and its estimator (camera, emulator; '' for a recorded one)
    for i, fl in enumerate(cfg.flights):
        ingest_id, sim_id, perception[ingest_id], estimator[ingest_id] = _flight_stages(
            graph, cfg, fl, i, base, wanted, src, progress
        )
        ingest_ids[fl.role].append(ingest_id)
        sim_ids[fl.role].append(sim_id)
    if "fit" not in wanted:
        return graph
    if not ingest_ids["train"]:
        raise ConfigError(f"{src('flights')}: the fit needs at least one flight with role 'train'")
    fit_opts = cfg.fit
    train = tuple(ingest_ids["train"])
    # simulated training flights logged their inputs: the disturbance is measured with them
    sims = [s for s in sim_ids["train"] if s is not None]
    logged = sims if len(sims) == len(train) and fit_opts.inputs is None else []
    execute = _fit_exec(fit_opts, list(train), logged, progress)
    graph.add(Stage("fit", "fit", fit_opts, execute, (*train, *logged), notes=_warnings))
    if cfg.sweep is not None and "sweep" in wanted:
        _sweep_stage(graph, cfg.sweep, progress)
    listed = set(cfg.stages or ())
    if "fly" in listed and cfg.fly is None:
        raise ConfigError(
            f"{src('stages')}: fly is listed but the config has no fly: section (the seeds, "
            "conditions and duration to fly): add one, or leave fly out"
        )
    if cfg.synth is None or "synth" not in wanted:
        for stage, verb in (("evaluate", "evaluate"), ("fly", "fly")):
            if stage in listed:
                raise ConfigError(
                    f"{src('stages')}: {stage} is listed but there are no controllers to "
                    f"{verb}: add a synth: section (and synth to the stages)"
                )
        return graph
    synth_opts = cfg.synth
    graph.add(Stage("synth", "synth", synth_opts, _synth_exec(synth_opts, progress), deps=("fit",)))
    calibrated = None
    if cfg.calibrate is not None and "calibrate" in wanted:
        calibrated = _calibrate_stage(graph, cfg, base, src, progress)
    heldout = ingest_ids["heldout"]
    if "evaluate" in wanted:
        if not heldout and ("evaluate" in listed or cfg.evaluate is not None):
            where = src("stages") if "evaluate" in listed else src("evaluate")
            raise ConfigError(
                f"{where}: evaluate is asked for but there is nothing to evaluate: no flight "
                "has role 'heldout'; add a held-out flight, or leave evaluate out (the "
                "controllers fly in a fly: section)"
            )
        # a held-out flight is checked with the default options when the section is left out
        if heldout:
            _evaluate_stages(
                graph, cfg.evaluate or EvaluateSection(), heldout, progress, calibrated,
                [perception[h] for h in heldout], [estimator[h] for h in heldout],
            )  # fmt: skip
    if cfg.fly is not None and "fly" in wanted:
        _fly_stage(graph, cfg, src, progress, calibrated)
    return graph


def _flight_stages(
    graph: StageGraph,
    cfg: RunConfig,
    fl: FlightSpec,
    i: int,
    base: Path,
    wanted: Collection[str],
    src: Src,
    progress: Progress,
) -> tuple[str, str | None, str, str]:
    """The flight's simulate stage (simulated flights) and its ingest stage: their ids, and
    the flight's perception condition and estimator (``''`` for a recorded flight)."""
    sources: list[Path] = []
    deps: tuple[str, ...] = ()
    perception = estimator = ""
    ingest_opts: dict[str, Any] = merge(cfg.written("ingest"), fl.ingest)
    if fl.simulate is not None:
        if "simulate" not in wanted and not (graph.root / "simulate" / fl.name).is_dir():
            raise ConfigError(
                f"flight '{fl.name}' is simulated but the run's stages leave out simulate"
            )
        sim_id, sim = _simulate_stage(graph, cfg, fl, i, src, progress)
        deps, perception, estimator = (sim_id,), sim.vio.perception, sim.vio.kind
    else:
        sources = [resolve_path(base, s) for s in fl.sources]
        for key in ("vio", "truth"):
            value = getattr(fl, key)
            if value is not None:
                ingest_opts[key] = str(resolve_path(base, value))
        if not sources and fl.vio is None:
            raise ConfigError(
                f"flight '{fl.name}': give 'simulate', 'sources' or 'vio' and 'truth'"
            )
        given = [*sources, *(Path(ingest_opts[k]) for k in ("vio", "truth") if k in ingest_opts)]
        missing = [p for p in given if not p.exists()]
        if missing:
            raw = [*fl.sources, *(v for v in (fl.vio, fl.truth) if v is not None)]
            raise ConfigError(f"flight '{fl.name}': {missing[0]} does not exist{missing_hint(raw)}")
    opts = validate(IngestOptions, ingest_opts, src(f"ingest (flight '{fl.name}')"))
    external = tuple(sources) + tuple(Path(p) for p in (opts.vio, opts.truth) if p is not None)
    stage_id = f"ingest/{fl.name}"
    graph.add(
        Stage(
            stage_id,
            "ingest",
            {"options": opts, "sources": [s.name for s in sources]},
            _ingest_exec(opts, sources, deps, progress),
            deps=deps,
            external=external,
            notes=_warnings,
        )
    )
    return stage_id, deps[0] if deps else None, perception, estimator


def _sweep_stage(graph: StageGraph, sec: SweepSection, progress: Progress) -> None:
    opts = sec.options()
    execute = _sweep_exec(opts, sec.jobs, sec.scheduler, sec.wait_workers, progress)
    graph.add(Stage("sweep", "sweep", opts, execute, deps=("fit",)))


def _evaluate_stages(
    graph: StageGraph,
    sec: EvaluateSection,
    heldout: list[str],
    progress: Progress,
    calibrated: str | None = None,
    conditions: list[str] | None = None,
    estimators: list[str] | None = None,
) -> None:
    """The bound check on the held-out flights (``conditions``: their perception,
    ``estimators`` their estimator, ``''`` for a recorded flight); with a calibration
    (``calibrated``: its first condition), each calibrated controller is checked against its
    certificate for the flight's condition."""
    cal = ("calibrate",) if calibrated is not None else ()
    eval_opts = sec.bound()
    conds = conditions if conditions is not None else [""] * len(heldout)
    ests = estimators if estimators is not None else [""] * len(heldout)
    execute = _evaluate_exec(eval_opts, heldout, progress, calibrated, conds, ests)
    deps = ("fit", "synth", *cal, *heldout)
    graph.add(Stage("evaluate", "evaluate", eval_opts, execute, deps=deps, notes=_verdicts))


def _fly_stage(
    graph: StageGraph, cfg: RunConfig, src: Src, progress: Progress, calibrated: str | None
) -> None:
    """The controllers flown (``fly:``, docs/evaluation.md), each checked against its own
    certificate (its condition's, with a calibration)."""
    cal = ("calibrate",) if calibrated is not None else ()
    # the flights fly the run's simulate: conditions, as the calibration's do (a flight of
    # other conditions is outside the certificate: docs/calibration.md)
    opts = flying(cfg.written("fly"), source=src("fly"), base_sim=cfg.written("simulate") or {})
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


def design_seeds(cfg: RunConfig) -> list[int]:
    """The seeds of the run's simulated flights (every role: the design saw them all)."""
    seeds = []
    for i, fl in enumerate(cfg.flights):
        if fl.simulate is not None:
            data = merge(cfg.written("simulate"), fl.simulate)
            seeds.append(int(data.get("seed", cfg.seed + i)))
    return seeds


def _calibrate_stage(
    graph: StageGraph, cfg: RunConfig, base: Path, src: Src, progress: Progress
) -> str:
    """The candidates' calibration and validation flights (docs/calibration.md), under the
    run's ``simulate:`` conditions, on seeds no design flight used."""
    given = cfg.written("calibrate") or {}
    data = merge(given, {"sim": merge(cfg.written("simulate"), given.get("sim") or {})})
    data["design_seeds"] = sorted(set(design_seeds(cfg)) | set(given.get("design_seeds") or []))
    opts = validate(CalibrateOptions, data, src("calibrate"))
    rec = opts.recorded  # the user's flights, where the config says, relative to it
    opts = opts.model_copy(update={"recorded": rec.model_copy(update={
        role: [resolve_path(base, p) for p in getattr(rec, role)]
        for role in ("calibration", "range", "validation")})})  # fmt: skip
    try:
        opts.seed_lists()
    except ConfigError as exc:
        raise ConfigError(f"{src('calibrate')}: {exc}") from None
    # checked here, against every simulated flight; the stage's outputs do not depend on them
    opts = opts.model_copy(update={"design_seeds": list(given.get("design_seeds") or [])})

    def execute(out: Path, deps: Mapping[str, Path]) -> Any:
        # deferred: a stage's code loads when it runs (a cached run loads none of it)
        from qsls.pipeline.calibrate.stage import calibrate, calibrate_recorded

        run = calibrate_recorded if opts.recorded.given or opts.source == "standin" else calibrate
        return run(deps["fit"], deps["synth"], opts, out, force=True, progress=progress)

    external = tuple(Path(p) for r in ("calibration", "range", "validation")
                     for p in getattr(opts.recorded, r))  # fmt: skip
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


def _simulate_stage(
    graph: StageGraph, cfg: RunConfig, fl: FlightSpec, i: int, src: Src, progress: Progress
) -> tuple[str, SimOptions]:
    """The flight's simulate stage: its id and its options."""
    data = merge(cfg.written("simulate"), fl.simulate or {})
    data.setdefault("seed", cfg.seed + i)
    opts = validate(SimOptions, data, src(f"simulate (flight '{fl.name}')"))
    stage_id = f"simulate/{fl.name}"

    def execute(out: Path, deps: Mapping[str, Path]) -> Any:
        # deferred: a stage's code loads when it runs (a cached run loads none of it)
        from qsls.pipeline.sim.simulate import simulate

        return simulate(opts, out, force=True, progress=progress)

    graph.add(Stage(stage_id, "simulate", opts, execute))
    return stage_id, opts


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


def _fly_exec(opts: FlyOptions, progress: Progress, calibrated: str | None = None) -> Execute:
    def execute(out: Path, deps: Mapping[str, Path]) -> Any:
        # deferred: a stage's code loads when it runs (a cached run loads none of it)
        from qsls.pipeline.fly.stage import fly_evaluate

        ctrls = controller_folders(deps, calibrated)
        return fly_evaluate(
            deps["fit"], ctrls, opts, out, force=True, progress=progress,
            by_condition=condition_folders(deps) if calibrated is not None else None,
        )  # fmt: skip

    return execute
