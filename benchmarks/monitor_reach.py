"""How close the onboard innovation monitor comes to the tightest sound test (issue 48,
docs/monitor.md#the-reach-of-a-sound-monitor)::

    python benchmarks/monitor_reach.py --model FIT --controller CERT_FOLDER FLY_OUT [...]

For each ``qsls fly`` output folder (its flights of the certified controller in
``CERT_FOLDER``), from each flight's own tick log: whether its premise broke (the flight
checks' first failing assumption), whether a flight keeping the premise reads the same (a
witness, checked with numpy alone and, as a flight, by the flight checks themselves against
the training states in ``FIT``: then no sound monitor of ``y`` and ``u`` can trip on it), else
the earliest tick any sound monitor can trip at, and when the window monitor tripped. Prints
one markdown row per folder; a flight neither explained nor broken within the solver's
tolerance is counted as undecided, and a window trip before the earliest possible one (which
the monitor's soundness forbids) in the last column.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import pandas as pd

from qsls.pipeline.control.artifacts import load_controller_dir
from qsls.pipeline.control.monitor import hover_input, premise_box_of, sound_innovation_of
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


def reach(fit: Path, controller: Path, out: Path) -> dict[str, object]:
    """One folder's row (module docstring)."""
    cdir = load_controller_dir(controller)
    training = load_training(resolve_model(fit)[1], load_error_model(fit), None)
    premise = premise_of(cdir)
    box, spec = premise_box_of(cdir), sound_innovation_of(cdir)
    if box is None:
        raise SystemExit(f"{controller}: its certificate has no innovation monitor")
    if not box.exact:  # a witness would keep a box around the premise, not the premise
        raise SystemExit(f"{controller}: its premise is not a box per tick (H, bias or S)")
    gate, u_hover = cdir.certificate.numbers().gate, hover_input(cdir)
    checks = pd.read_parquet(out / "assumptions.parquet").set_index("flight")
    rows = []
    for name in checks.index[checks["controller"] == controller.name]:
        log = TickLog.read(out / "flights" / name / TICKS_FILE)
        nu = innovations(spec, log, u_hover, gate)
        wit = premise_witness(nu, box)
        explained = (
            wit is not None
            and premise is not None
            and witness_problems(wit, nu, box) == []
            and check_assumptions(witness_flight(wit, log, gate), premise, training.distance)[
                "assumptions_hold"
            ]
        )
        L = None if explained else earliest_break(nu, box)
        first = checks.at[name, "first_failed"]
        rows.append({
            "broken": isinstance(first, str) and bool(first),
            "explained": explained,
            "exact_t": float(log.t[L] - log.t[0]) if L is not None else math.nan,
            "undecided": not explained and L is None,
            "monitor_t": float(checks.at[name, "monitor_t"]),
        })  # fmt: skip
    df = pd.DataFrame(rows)
    early = int((df["monitor_t"] < df["exact_t"] - 1e-9).sum())
    return {
        "flights": out.name,
        "n": len(df),
        "premise broken": int(df["broken"].sum()),
        "explained by a witness": int(df["explained"].sum()),
        "undecided": int(df["undecided"].sum()),
        "earliest sound trip (mean s)": round(float(np.nanmean(df["exact_t"])), 2)
        if df["exact_t"].notna().any()
        else "-",
        "window monitor tripped": int(df["monitor_t"].notna().sum()),
        "its trip (mean s)": round(float(np.nanmean(df["monitor_t"])), 2)
        if df["monitor_t"].notna().any()
        else "-",
        "tripped before the earliest": early,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, required=True, help="the fit folder")
    ap.add_argument("--controller", type=Path, required=True)
    ap.add_argument("outs", type=Path, nargs="+")
    args = ap.parse_args()
    rows = [reach(args.model, args.controller, out) for out in args.outs]
    print("| " + " | ".join(rows[0]) + " |")
    print("|" + "---|" * len(rows[0]))
    for r in rows:
        print("| " + " | ".join(str(v) for v in r.values()) + " |")


if __name__ == "__main__":
    main()
