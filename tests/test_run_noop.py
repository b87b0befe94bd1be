"""A run with nothing to do (issue 27) and what the run cache key holds (issue 24): the
up-to-date rerun runs no stage and imports no heavy package, yet notices a deleted or edited
output; the key changes with the qsls and numerical package versions; an input is hashed
again only when a file of it changed size or mtime."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest
import yaml

from qsls.pipeline.core.artifacts import StageWriter, sha256_path
from qsls.pipeline.evaluate.verdict import read_verdicts
from qsls.pipeline.run.graph import Stage, StageGraph, run_versions
from qsls.pipeline.run.state import RunState
from tests.test_run import _statuses
from tests.test_run_cache import SMALL

HEAVY = ("cvxpy", "scipy", "matplotlib", "pandas", "rotorpy", "dask", "pyarrow", "clarabel")


def _qsls(*args: object, cwd: Path, env: dict[str, str] | None = None, importtime: bool = False):
    flags = ["-X", "importtime"] if importtime else []
    return subprocess.run(
        [sys.executable, *flags, "-m", "qsls.cli.main", *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
        env=env,
    )


def _ran(proc: subprocess.CompletedProcess) -> set[str]:
    assert proc.returncode == 0, proc.stderr[-3000:]
    return {k for k, v in _statuses(proc.stderr).items() if v == "ran"}


def _verdict_lines(stdout: str) -> list[str]:
    lines = stdout.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("Certified bound on"))
    return lines[start:]


def _imported(stderr: str) -> set[str]:
    """Top-level packages a ``python -X importtime`` process imported."""
    names = re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s+(\S+)$", stderr, re.M)
    return {n.split(".")[0] for n in names}


# ----------------------------------------------------------------- the run with nothing to do
@pytest.mark.slow
def test_an_up_to_date_rerun_runs_nothing_imports_nothing_heavy_and_notices_changed_outputs(
    tmp_path,
):
    data = {
        **SMALL,
        "flights": [
            *SMALL["flights"],
            {"name": "held", "role": "heldout", "simulate": {"seed": 3}},
        ],
        "evaluate": {},
        "report": True,
    }
    cfg = tmp_path / "small.yaml"
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    run = tmp_path / "runs" / "small"
    index = run / "report" / "index.html"

    first = _qsls("run", cfg, cwd=tmp_path)
    assert "evaluate" in _ran(first) and index.is_file()
    verdicts = _verdict_lines(first.stdout)
    assert verdicts[1:] == [f"  {x}" for v in read_verdicts(run / "evaluate") for x in v.lines()]
    assert any(v.startswith("  l1_robust: ") for v in verdicts)
    report_stamp = index.stat().st_mtime_ns

    noop = _qsls("run", cfg, cwd=tmp_path, importtime=True)
    assert _ran(noop) == set()
    assert set(_statuses(noop.stderr)) == {
        "simulate/train_1", "ingest/train_1", "simulate/train_2", "ingest/train_2",
        "simulate/held", "ingest/held", "fit", "synth", "evaluate",
    }  # fmt: skip
    assert _verdict_lines(noop.stdout) == verdicts  # from the run state, not the table
    assert index.stat().st_mtime_ns == report_stamp  # the report was not written again
    assert _imported(noop.stderr) & set(HEAVY) == set()

    (run / "ingest" / "held" / "flight.parquet").unlink()
    proc = _qsls("run", cfg, cwd=tmp_path)
    assert _ran(proc) == {"ingest/held", "evaluate"}
    assert "flight.parquet is missing" in proc.stderr
    assert _verdict_lines(proc.stdout) == verdicts
    assert index.stat().st_mtime_ns != report_stamp  # a stage ran: the report follows

    table = next(p for p in (run / "evaluate").iterdir() if p.suffix in (".parquet", ".csv"))
    with open(table, "ab") as fh:
        fh.write(b"edited")
    proc = _qsls("run", cfg, cwd=tmp_path)
    assert _ran(proc) == {"evaluate"}
    assert f"{table.name} changed" in proc.stderr
    assert _verdict_lines(proc.stdout) == verdicts

    # the report is checked like a stage: a deleted page is written again, alone
    index.unlink()
    proc = _qsls("run", cfg, cwd=tmp_path)
    assert _ran(proc) == set() and index.is_file()

    # an edited config is planned again (validated): a misspelled option is still refused
    cfg.write_text(cfg.read_text().replace("fit:\n  radius: 1.0", "fit:\n  radiuss: 1.0"))
    proc = _qsls("run", cfg, cwd=tmp_path)
    assert proc.returncode != 0 and "radiuss" in proc.stderr and "Traceback" not in proc.stderr


# ----------------------------------------------------------------- the cache key (issue 24)
def _graph(root: Path, inputs: list[Path], calls: list[str], **kw) -> StageGraph:
    def ingest(out: Path, deps) -> None:
        calls.append("ingest")
        with StageWriter(out, "ingest", force=True) as w:
            w.write_text("n.txt", str(sum(p.stat().st_size for p in inputs)))

    def fit(out: Path, deps) -> None:
        calls.append("fit")
        with StageWriter(out, "fit", force=True) as w:
            w.write_text("m.txt", (deps["ingest"] / "n.txt").read_text())

    g = StageGraph(root, **kw)
    g.add(Stage("ingest", "ingest", {"dt": 0.1}, ingest, external=tuple(inputs)))
    g.add(Stage("fit", "fit", {"radius": 1.0}, fit, deps=("ingest",)))
    return g


def test_an_unchanged_input_is_not_hashed_again(tmp_path):
    bag = tmp_path / "bag"  # a rosbag2-like folder, and a single file
    bag.mkdir()
    (bag / "metadata.yaml").write_text("version: 5\n")
    (bag / "bag_0.db3").write_bytes(os.urandom(4096))
    log = tmp_path / "truth.txt"
    log.write_text("0 0 0 0 0 0 0 1\n")
    files = sorted([bag / "bag_0.db3", bag / "metadata.yaml", log])
    root = tmp_path / "run"
    calls: list[str] = []

    g = _graph(root, [bag, log], calls)
    g.run()
    assert calls == ["ingest", "fit"] and sorted(g.hashes.hashed) == files
    recorded = RunState.load(root).inputs
    assert recorded[str(bag)].sha256 == sha256_path(bag)
    assert set(recorded[str(bag)].files) == {str(bag / "bag_0.db3"), str(bag / "metadata.yaml")}

    calls.clear()
    g = _graph(root, [bag, log], calls)
    assert {o.status for o in g.run()} == {"skipped"}
    assert calls == [] and g.hashes.hashed == []  # no byte of the inputs read

    # same bytes, new mtime: that file alone is hashed, found unchanged, nothing runs
    os.utime(bag / "bag_0.db3", ns=(1, 1))
    g = _graph(root, [bag, log], calls)
    assert {o.status for o in g.run()} == {"skipped"} and calls == []
    assert g.hashes.hashed == [bag / "bag_0.db3"]
    g = _graph(root, [bag, log], calls)
    g.run()
    assert g.hashes.hashed == []  # the new mtime was recorded

    # new bytes (and so a new mtime): hashed, and the stages rerun
    (bag / "bag_0.db3").write_bytes(os.urandom(4096))
    g = _graph(root, [bag, log], calls)
    outcomes = g.run()
    assert g.hashes.hashed == [bag / "bag_0.db3"] and calls == ["ingest", "fit"]
    assert outcomes[0].reason == "its options or inputs changed"

    # a file added to the bag folder changes the folder's hash
    calls.clear()
    (bag / "bag_1.db3").write_bytes(b"more")
    g = _graph(root, [bag, log], calls)
    g.run()
    assert g.hashes.hashed == [bag / "bag_1.db3"] and calls == ["ingest", "fit"]


@pytest.mark.parametrize("package", ["qsls", "cvxpy", "clarabel", "numpy", "rotorpy"])
def test_a_changed_package_version_reruns_the_stages(tmp_path, package):
    versions = run_versions()
    for name in ("cvxpy", "clarabel", "numpy", "scipy", "rotorpy"):  # as manifests record
        assert versions[name] == version(name)
    calls: list[str] = []
    _graph(tmp_path, [], calls, versions=versions).run()
    calls.clear()
    _graph(tmp_path, [], calls, versions=versions).run()
    assert calls == []

    upgraded = {**versions, package: "99.0"}
    outcomes = _graph(tmp_path, [], calls, versions=upgraded).run()
    assert calls == ["ingest", "fit"]
    why = f"package versions changed ({package} {versions[package]} -> 99.0)"
    assert [o.reason for o in outcomes] == [why, why]
    calls.clear()
    _graph(tmp_path, [], calls, versions=upgraded).run()
    assert calls == []


@pytest.mark.slow
def test_a_qsls_run_notices_another_installed_solver_version(tmp_path):
    """A real ``qsls run`` whose environment holds another cvxpy distribution (metadata
    first on the path, as after an upgrade) reruns its stages; the same environment again
    does not."""
    data = {**SMALL, "flights": SMALL["flights"][:1], "stages": ["simulate", "ingest"]}
    cfg = tmp_path / "small.yaml"
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    assert _ran(_qsls("run", cfg, cwd=tmp_path)) == {"simulate/train_1", "ingest/train_1"}
    assert _ran(_qsls("run", cfg, cwd=tmp_path)) == set()

    meta = tmp_path / "site" / "cvxpy-0.0.1.dist-info"
    meta.mkdir(parents=True)
    (meta / "METADATA").write_text("Metadata-Version: 2.1\nName: cvxpy\nVersion: 0.0.1\n")
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "site")}
    proc = _qsls("run", cfg, cwd=tmp_path, env=env)
    assert _ran(proc) == {"simulate/train_1", "ingest/train_1"}
    assert f"package versions changed (cvxpy {version('cvxpy')} -> 0.0.1)" in proc.stderr
    assert _ran(_qsls("run", cfg, cwd=tmp_path, env=env)) == set()
    state = json.loads((tmp_path / "runs" / "small" / "run_state.json").read_text())
    assert state["stages"]["ingest/train_1"]["versions"]["cvxpy"] == "0.0.1"


def test_a_touched_output_is_hashed_once_and_an_edited_one_reruns(tmp_path):
    calls: list[str] = []
    _graph(tmp_path, [], calls).run()
    out = tmp_path / "fit" / "m.txt"
    recorded = RunState.load(tmp_path).stages["fit"].files["m.txt"]

    os.utime(out, ns=(5, 5))  # same bytes, another mtime: hashed, restamped, skipped
    calls.clear()
    assert {o.status for o in _graph(tmp_path, [], calls).run()} == {"skipped"}
    restamped = RunState.load(tmp_path).stages["fit"].files["m.txt"]
    assert (restamped.mtime_ns, restamped.sha256) == (5, recorded.sha256)

    out.write_text("9" * len(out.read_text()))  # same size, other bytes
    outcomes = _graph(tmp_path, [], calls).run()
    assert calls == ["fit"] and outcomes[1].reason == "output m.txt changed"
