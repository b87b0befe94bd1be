"""``qsls run`` with nothing to do, as a fresh process, against the way it was done before.

Issue 27's target: ``qsls run configs/quickstart.yaml`` when everything is up to date in at
most 1 s, interpreter start included. Each row is a fresh process on a run folder that is
up to date (the run is made once first, untimed):

- ``qsls run``: the command (the last plan reused from the run state, inputs re-hashed only
  when their size or mtime changed, outputs checked by size and mtime, the verdict lines
  from the run state, the report left alone when nothing changed);
- the previous way, through the same library: plan the config (validating every stage's
  options, which imports every stage's module), hash every external input, check every
  stage's outputs, read the verdicts from the evaluation tables, and write the report again
  (``qsls run`` did all of these on every run);
- ``qsls --version``: the floor (interpreter start and the CLI's imports).

Two configs: the quickstart (simulated flights: no external input), and one flight ingested
from the 200 000-message sqlite3 bag of ``bench_ingest_process.py`` (107 MB), where the
previous way hashes the bag on every run.

Run: python benchmarks/bench_run.py [--repeat N] [--clean] [--smoke]

``--smoke`` (``smokemode.py``): instead of the quickstart a run of two 8 s simulated flights
through simulate, ingest and fit (:data:`SMOKE_CONFIG`), a 2 000-message bag, one run per
cell, all in a temporary folder.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_ingest import build, size_mb
from fresh import WORK, best_walls, fresh_env
from smokemode import add_flag

ROOT = Path(__file__).resolve().parents[1]

PREVIOUS = r"""
import sys
from pathlib import Path

from qsls.cli.common import print_summary, print_verdicts
from qsls.pipeline.evaluate.verdict import read_verdicts
from qsls.pipeline.report.stage import report
from qsls.pipeline.run.runner import load_run_config, plan
from qsls.pipeline.run.state import RunState

config, root = Path(sys.argv[1]), Path(sys.argv[2]).resolve()
cfg = load_run_config(config)
graph = plan(cfg, config, root)  # every stage's options validated: every stage imported
keys = graph.keys()  # no recorded stamps: every input hashed
state = RunState.load(root)
stale = [s.id for s in graph.stages if state.check(s.id, keys[s.id], graph.folder(s.id))[0]]
assert not stale, stale
print_summary("qsls run", {"stages up to date (skipped)": len(graph.stages)})
for stage in ("evaluate", "fly"):
    print_verdicts(stage, read_verdicts(root / stage))
if cfg.report:
    report(root, Path("reports") / cfg.name, force=True)
"""


SMOKE_CONFIG = """name: smoke
stages: [simulate, ingest, fit]
report: false
simulate: {duration: 8, controller: {kind: pd}}
flights:
  - {name: train_1, role: train, simulate: {seed: 1}}
  - {name: train_2, role: train, simulate: {seed: 2, log: {format: ros2-mcap}}}
ingest: {dt: 0.1}
"""
"""The smoke mode's stand-in for the quickstart: simulated flights, no external input."""


def setup(work: Path, bag: Path, smoke: bool = False) -> dict[str, Path]:
    """The configs, each run once (untimed) so that their run folders are up to date."""
    work.mkdir(parents=True, exist_ok=True)
    quick = work / ("smoke.yaml" if smoke else "quickstart.yaml")
    quick.write_text(SMOKE_CONFIG if smoke else (ROOT / "configs" / "quickstart.yaml").read_text())
    big = work / "bag.yaml"
    big.write_text(
        "name: bag\nstages: [ingest]\nreport: false\n"
        f"flights:\n  - {{name: big, sources: ['{bag}'], "
        "ingest: {vio_topic: /vio/odom, truth_topic: /mocap/pose}}\n"
    )
    configs = {
        f"{quick.stem} (simulated flights)": quick,
        f"one {size_mb(bag):.0f} MB sqlite3 bag": big,
    }
    for c in configs.values():
        cmd = [sys.executable, "-m", "qsls.cli.main", "run", str(c)]
        done = subprocess.run(cmd, capture_output=True, text=True, cwd=work, env=fresh_env())
        if done.returncode:
            raise SystemExit(f"qsls run {c.name} failed: {done.stderr.strip()[-400:]}")
    return configs


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5, help="fresh processes per cell (best)")
    ap.add_argument("--clean", action="store_true", help="redo the runs from scratch")
    add_flag(ap)
    args = ap.parse_args()
    work = WORK / "run_bench"
    if args.clean:
        shutil.rmtree(work, ignore_errors=True)
    if args.smoke:
        args.repeat = 1
        bag = build(1_000, 0.0, None, "a_smoke_ros2-sqlite", "ros2-sqlite")
    else:
        bag = build(100_000, 0.0, None, "a_full_ros2-sqlite", "ros2-sqlite")
    configs = setup(work, bag, args.smoke)
    floor = best_walls({"v": [sys.executable, "-m", "qsls.cli.main", "--version"]}, args.repeat)
    rows = []
    for label, cfg in configs.items():
        run_dir = work / "runs" / cfg.stem
        t = best_walls(
            {
                "new": [sys.executable, "-m", "qsls.cli.main", "run", str(cfg)],
                "old": [sys.executable, "-c", PREVIOUS, str(cfg), str(run_dir)],
            },
            args.repeat,
            work,
        )
        if not re.search(r"stages run\W+0\W", t["new"][2]):
            raise SystemExit(f"{cfg.name}: qsls run was not a no-op:\n{t['new'][2]}")
        rows.append((label, t["new"], t["old"]))
    print(
        f"\nqsls run with nothing to do, a fresh process each: best wall seconds of"
        f" {args.repeat}, taken in turns (least CPU seconds)\n"
    )
    head = f"{'config':32s} | {'qsls run':>13s} | {'previous way':>13s} {'speed-up':>8s}"
    print(head)
    print("-" * len(head))
    for label, (n, nc, _), (o, oc, _) in rows:
        print(f"{label:32s} | {n:5.2f} ({nc:4.2f}) | {o:5.2f} ({oc:4.2f}) {o / n:7.1f}x")
    print(
        f"\nfloor, qsls --version: {floor['v'][0]:.2f} s ({floor['v'][1]:.2f} s CPU). Target: the"
        " quickstart row's qsls run <= 1 s."
    )


if __name__ == "__main__":
    main()
