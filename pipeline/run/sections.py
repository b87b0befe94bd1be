"""A run config resolved into each stage's typed options, in one pass (docs/run.md#sections).

:func:`resolve_sections` does everything a config needs before a stage graph can be built
from it: each flight's ``simulate:`` and ``ingest:`` laid over the run's sections as they
were written and validated (errors naming the flight), the paths taken relative to the
config's folder (:func:`qsls.pipeline.run.paths.resolve_path`) and checked to exist, the
run's ``simulate:`` laid under ``calibrate.sim`` and ``fly.sim``, the calibration's seeds
checked against every design flight's. What it returns, :class:`Sections`, is frozen and
typed; :func:`qsls.pipeline.run.stages.build_graph` only turns it into stages. Checks that
depend on which stages a run asks for (``stages:``) are the graph's, not made here.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from qsls.pipeline.calibrate.options import CalibrateOptions
from qsls.pipeline.control.options import SweepSection, SynthOptions
from qsls.pipeline.core.config import layered
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.errormodel.options import FitOptions
from qsls.pipeline.evaluate.options import EvaluateOptions
from qsls.pipeline.fly.options import FlyOptions, flying
from qsls.pipeline.ingest.options import IngestOptions
from qsls.pipeline.run.paths import missing_hint, resolve_path
from qsls.pipeline.run.runconfig import FlightSpec, RunConfig
from qsls.pipeline.sim.options import SimOptions


@dataclass(frozen=True)
class ResolvedFlight:
    """One flight of the run, resolved: its simulation's options (``None`` for a recorded
    flight), its ingest's (``vio``/``truth`` absolute) and a recorded flight's source files."""

    name: str
    role: Literal["train", "heldout"]
    """``train`` (the fit's) or ``heldout`` (the bound check's)."""
    sim: SimOptions | None
    ingest: IngestOptions
    sources: tuple[Path, ...] = ()

    @property
    def perception(self) -> str:
        """A simulated flight's perception condition; ``''`` for a recorded one."""
        return self.sim.vio.perception if self.sim is not None else ""

    @property
    def estimator(self) -> str:
        """A simulated flight's estimator (camera, emulator); ``''`` for a recorded one."""
        return self.sim.vio.kind if self.sim is not None else ""

    @property
    def external(self) -> tuple[Path, ...]:
        """The files its ingest reads from outside the run folder."""
        logs = (self.ingest.vio, self.ingest.truth)
        return self.sources + tuple(Path(p) for p in logs if p is not None)


@dataclass(frozen=True)
class Sections:
    """Every stage's options of one run config, typed and resolved (:func:`resolve_sections`);
    ``None`` where the config leaves a section out."""

    base: Path
    """The config's folder: its paths were taken relative to it, and errors name it."""
    flights: tuple[ResolvedFlight, ...]
    fit: FitOptions
    sweep: SweepSection | None
    synth: SynthOptions | None
    calibrate: CalibrateOptions | None
    evaluate: EvaluateOptions | None
    fly: FlyOptions | None

    def source(self, section: str) -> str:
        """How an error names ``section`` of the config."""
        return f"{self.base}: {section}"


def resolve_sections(cfg: RunConfig, base: Path) -> Sections:
    """``cfg``'s sections as each stage's options, paths relative to ``base``; a
    :class:`ConfigError` naming the section (and the flight) for the first one that is wrong."""
    base = Path(base)
    if not cfg.flights:
        raise ConfigError(f"{base}: flights: a run needs at least one flight")
    # the sections as the file wrote them: what the flights, calibrate.sim and fly.sim lay
    # their own keys over (a default of the model is not a key the user gave)
    sim, ingest = cfg.written("simulate"), cfg.written("ingest")
    flights = tuple(
        _flight(fl, cfg.seed + i, sim, ingest, base) for i, fl in enumerate(cfg.flights)
    )
    calibrate = None
    if cfg.calibrate is not None:
        calibrate = _calibrate(cfg.written("calibrate") or {}, sim, _design_seeds(flights), base)
    # the flights fly the run's simulate: conditions, as the calibration's do (a flight of
    # other conditions is outside the certificate: docs/calibration.md)
    fly = None
    if cfg.fly is not None:
        fly = flying(cfg.written("fly"), source=f"{base}: fly", base_sim=sim)
    return Sections(
        base=base,
        flights=flights,
        fit=cfg.fit,
        sweep=cfg.sweep,
        synth=cfg.synth,
        calibrate=calibrate,
        evaluate=cfg.evaluate.bound() if cfg.evaluate is not None else None,
        fly=fly,
    )


def _design_seeds(flights: tuple[ResolvedFlight, ...]) -> list[int]:
    """The seeds of the run's simulated flights (every role: the design saw them all)."""
    return [f.sim.seed for f in flights if f.sim is not None]


def _flight(
    fl: FlightSpec,
    seed: int,
    sim: Mapping[str, Any],
    ingest: Mapping[str, Any],
    base: Path,
) -> ResolvedFlight:
    """Flight ``fl``: its own ``simulate:`` / ``ingest:`` over the run's ``sim`` / ``ingest``
    (its seed, unless one of them gives it, ``seed``: the run's plus the flight's index); a
    recorded flight's paths relative to ``base``."""
    sim_opts = None
    sources: tuple[Path, ...] = ()
    logs: dict[str, Any] = {}
    if fl.simulate is not None:
        sim_opts = layered(
            SimOptions,
            {"seed": seed, **sim},
            fl.simulate,
            source=f"{base}: simulate (flight '{fl.name}')",
        )
    else:
        sources = tuple(resolve_path(base, s) for s in fl.sources)
        logs = {
            k: str(resolve_path(base, v))
            for k, v in (("vio", fl.vio), ("truth", fl.truth))
            if v is not None
        }
        if not sources and fl.vio is None:
            raise ConfigError(
                f"flight '{fl.name}': give 'simulate', 'sources' or 'vio' and 'truth'"
            )
        _refuse_missing(fl, [*sources, *(Path(v) for v in logs.values())])
    opts = layered(
        IngestOptions, ingest, fl.ingest, logs, source=f"{base}: ingest (flight '{fl.name}')"
    )
    flight = ResolvedFlight(name=fl.name, role=fl.role, sim=sim_opts, ingest=opts, sources=sources)
    if sim_opts is None:  # the run's ingest: may name the logs too
        _refuse_missing(fl, flight.external)
    return flight


def _refuse_missing(fl: FlightSpec, paths: Sequence[Path]) -> None:
    """A recorded flight's first file that does not exist, refused with a hint."""
    missing = [p for p in paths if not p.exists()]
    if missing:
        raw = [*fl.sources, *(v for v in (fl.vio, fl.truth) if v is not None)]
        raise ConfigError(f"flight '{fl.name}': {missing[0]} does not exist{missing_hint(raw)}")


def _calibrate(
    given: Mapping[str, Any], sim: Mapping[str, Any], designed: list[int], base: Path
) -> CalibrateOptions:
    """The candidates' calibration and validation flights (docs/calibration.md): the
    ``calibrate:`` section ``given`` under the run's ``simulate:`` conditions ``sim``, on seeds
    no design flight (``designed``) used; the recorded flights' folders relative to ``base``."""
    source = f"{base}: calibrate"
    own = list(given.get("design_seeds") or [])
    opts = layered(
        CalibrateOptions,
        {**given, "sim": sim},
        {"sim": given.get("sim") or {}},
        {"design_seeds": sorted(set(designed) | set(own))},
        source=source,
    )
    rec = opts.recorded  # the user's flights, where the config says, relative to it
    opts = opts.model_copy(update={"recorded": rec.model_copy(update={
        role: [resolve_path(base, p) for p in paths] for role, paths in rec.by_role.items()
    })})  # fmt: skip
    try:
        opts.seed_lists()
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    # checked here, against every simulated flight; the stage's outputs do not depend on them
    return opts.model_copy(update={"design_seeds": own})
