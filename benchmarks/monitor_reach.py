"""How close the onboard innovation monitor comes to the tightest sound test (issue 48,
docs/monitor.md#the-reach-of-a-sound-monitor)::

    python benchmarks/monitor_reach.py --model FIT --controller CERT [FLY_OUT ...] [--smoke]

For each family of flights of the certified controller in ``CERT`` (``qsls fly`` output folders
``FLY_OUT``; none given: the families of docs/monitor.md are flown first, through
configs/quickstart.yaml's ``simulate:`` and ``fly.sim``, seeds 600-609, 15 s, into
``benchmarks/_work/monitor_reach``), from each flight's own tick log:
- whether its premise broke (the flight checks' first failing assumption);
- whether a flight keeping the premise reads the same: a witness, checked with numpy alone
  and, as a flight, by the flight checks themselves against the training states in ``FIT``
  (then no sound monitor of ``y`` and ``u`` can trip on it; a witness that keeps the per-tick
  premise but breaks an assumption no monitor of ``y`` and ``u`` reads, the reference or the
  invariance, is counted apart);
- else the earliest tick any sound monitor can trip at, against the window monitor's trip.
One row per family. A flight neither explained nor broken within the solver's tolerance is
counted as undecided; a window trip before the earliest possible one, which the monitor's
soundness forbids, fails the run.

``--smoke`` (``smokemode.py``): two 8 s training flights, a fit and a synthesis at T = 20 and
S = 0 in a temporary folder, then one 4 s flight in still air and one in a 3 m/s wind.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from smokemode import add_flag, require, scratch, work_dir

from qsls.pipeline.control.artifacts import load_controller_dir
from qsls.pipeline.control.monitor import hover_input, premise_box_of, sound_innovation_of
from qsls.pipeline.core.config import merge, read_yaml
from qsls.pipeline.core.ticks import TickLog
from qsls.pipeline.errormodel.model import load_error_model, resolve_model
from qsls.pipeline.evaluate.assumptions import check_assumptions
from qsls.pipeline.evaluate.certified import premise_of
from qsls.pipeline.evaluate.training import load_training
from qsls.pipeline.evaluate.witness import (
    earliest_break,
    innovations,
    premise_witness,
    witness_flight,
    witness_problems,
)
from qsls.pipeline.sim.ticks import TICKS_FILE

REPO = Path(__file__).resolve().parents[1]
FAMILIES: dict[str, dict[str, Any]] = {
    "nominal": {"conditions": ["regular"]},
    "wind 1.0 m/s": {"conditions": ["regular"], "sim": {"wind": {"speed": 1.0}}},
    "wind 1.5 m/s": {"conditions": ["regular"], "sim": {"wind": {"speed": 1.5}}},
    "wind 2.0 m/s": {"conditions": ["regular"], "sim": {"wind": {"speed": 2.0}}},
    "wind 2.5 m/s": {"conditions": ["regular"], "sim": {"wind": {"speed": 2.5}}},
    "wind 3.0 m/s": {"conditions": ["regular"], "sim": {"wind": {"speed": 3.0}}},
    "degraded light": {"conditions": ["degraded"]},
}
"""The families of docs/monitor.md, laid over the flying options."""
SMOKE_FAMILIES = {k: FAMILIES[k] for k in ("nominal", "wind 3.0 m/s")}


def reach(fit: Path, controller: Path, out: Path) -> dict[str, Any]:
    """One family's row (module docstring)."""
    cdir = load_controller_dir(controller)
    box, spec, premise = premise_box_of(cdir), sound_innovation_of(cdir), premise_of(cdir)
    require(box is not None and premise is not None, f"{controller} has an innovation monitor")
    assert box is not None and premise is not None
    # a witness would keep a box around the premise, not the premise (H, bias or S)
    require(box.exact, f"{controller}'s premise is a box per tick")
    training = load_training(resolve_model(fit)[1], load_error_model(fit), None)
    gate, u_hover = cdir.certificate.numbers().gate, hover_input(cdir)
    checks = pd.read_parquet(out / "assumptions.parquet").set_index("flight")
    rows = []
    for name in checks.index[checks["controller"] == controller.name]:
        log = TickLog.read(out / "flights" / name / TICKS_FILE)
        nu = innovations(spec, log, u_hover, gate)
        wit = premise_witness(nu, box)
        boxed = wit is not None and witness_problems(wit, nu, box) == []
        held = boxed and bool(
            check_assumptions(witness_flight(wit, log, gate), premise, training.distance)[
                "assumptions_hold"
            ]
        )
        L = None if boxed else earliest_break(nu, box)
        first = checks.at[name, "first_failed"]
        rows.append({
            "broken": isinstance(first, str) and bool(first),
            "explained": held,
            "elsewhere": boxed and not held,
            "undecided": not boxed and L is None,
            "exact_t": float(log.t[L]) if L is not None else math.nan,
            "monitor_t": float(checks.at[name, "monitor_t"]),
        })  # fmt: skip
    df = pd.DataFrame(rows)
    return {
        "flights": len(df),
        "premise broken": int(df["broken"].sum()),
        "explained by a witness": int(df["explained"].sum()),
        "witness breaks another assumption": int(df["elsewhere"].sum()),
        "undecided": int(df["undecided"].sum()),
        "earliest sound trip (mean s)": _mean(df["exact_t"]),
        "window monitor tripped": int(df["monitor_t"].notna().sum()),
        "its trip (mean s)": _mean(df["monitor_t"]),
        # a trip on a flight a witness explains (no break at all) is one before the earliest
        "tripped before the earliest": int(
            (
                (df["monitor_t"] < df["exact_t"] - 1e-9)
                | (df["explained"] & df["monitor_t"].notna())
            ).sum()
        ),
    }


def _mean(v: pd.Series) -> str:
    return f"{float(np.nanmean(v)):.2f}" if v.notna().any() else "-"


def fly_families(
    fit: Path, controller: Path, families: dict[str, dict[str, Any]], root: Path, smoke: bool
) -> dict[str, Path]:
    """Each family flown by ``controller`` (``qsls fly``'s stage), its output folder."""
    from qsls.pipeline.fly.options import flying
    from qsls.pipeline.fly.stage import fly_evaluate

    if smoke:
        base: dict[str, Any] = {"seeds": [600], "duration": 4.0}
        sim: dict[str, Any] = {}
    else:
        cfg = read_yaml(REPO / "configs" / "quickstart.yaml")
        base = {"seeds": list(range(600, 610)), "duration": 15.0,
                "sim": dict(cfg["fly"].get("sim") or {})}  # fmt: skip
        sim = dict(cfg["simulate"])
    outs = {}
    for name, family in families.items():
        opts = flying(merge(base, family), {"figures": False}, name, base_sim=sim)
        out = root / name.replace(" ", "_").replace("/", "")
        fly_evaluate(fit, [controller], opts, out, force=True)
        outs[name] = out
    return outs


def prepare(root: Path) -> tuple[Path, Path]:
    """Smoke: two 8 s training flights -> ingest -> fit -> synth (T 20, S 0); the fit folder
    and the certified ``l1_robust``."""
    from qsls.pipeline.control.synth import SynthOptions, synth
    from qsls.pipeline.errormodel.fit import FitOptions, fit
    from qsls.pipeline.ingest.stage import IngestOptions, ingest
    from qsls.pipeline.sim.simulate import SimOptions, simulate

    flights = []
    for seed in (100, 101):
        res = simulate(SimOptions(seed=seed, duration=8.0), root / f"sim{seed}", force=True)
        ingest([res.bag], IngestOptions(), root / f"train{seed}", force=True)
        flights.append(root / f"train{seed}")
    fit(flights, FitOptions(radius=1.0), root / "fit", force=True)
    opts = SynthOptions(T=20, S=0.0, eps_e="p99", controllers="single")
    synth(root / "fit", opts, root / "synth", force=True)
    return root / "fit", root / "synth" / "l1_robust"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, help="the fit folder")
    ap.add_argument("--controller", type=Path, help="the certified controller's folder")
    ap.add_argument("outs", type=Path, nargs="*", help="qsls fly output folders")
    add_flag(ap)
    args = ap.parse_args()
    if args.smoke:
        args.model, args.controller = prepare(scratch())
    elif args.model is None or args.controller is None:
        ap.error("give --model and --controller (or --smoke)")
    if args.outs:
        outs = {p.name: p for p in args.outs}
    else:
        families = SMOKE_FAMILIES if args.smoke else FAMILIES
        root = work_dir(REPO / "benchmarks" / "_work" / "monitor_reach")
        outs = fly_families(args.model, args.controller, families, root, args.smoke)
    rows = {name: reach(args.model, args.controller, out) for name, out in outs.items()}
    cols = list(next(iter(rows.values())))
    print("| family | " + " | ".join(cols) + " |")
    print("|---|" + "---:|" * len(cols))
    for name, r in rows.items():
        print(f"| {name} | " + " | ".join(str(v) for v in r.values()) + " |")
    require(all(r["tripped before the earliest"] == 0 for r in rows.values()),
            "no window trip before the earliest possible sound trip")  # fmt: skip


if __name__ == "__main__":
    main()
