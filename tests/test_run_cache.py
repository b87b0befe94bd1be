"""`qsls run` trusts nothing it did not check (issue 16): the run cache verifies each stage's
outputs, one run at a time per folder, SIGTERM / SIGKILL leave nothing behind, --from report."""

from __future__ import annotations

import glob
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from qsls.pipeline.core.locks import FolderLock
from tests.test_run import _statuses

SMALL = {
    "name": "small",
    "seed": 0,
    "simulate": {
        "duration": 8,
        "reference": {"kind": "circle", "radius": 1.0, "period": 5.0, "height": 1.0},
        "controller": {"kind": "se3"},
    },
    "flights": [
        {"name": "train_1", "role": "train", "simulate": {"seed": 1}},
        {"name": "train_2", "role": "train", "simulate": {"seed": 2}},
    ],
    "ingest": {"dt": 0.1},
    "fit": {"radius": 1.0},
    "synth": {"T": 5, "S": 0.01, "eps_e": "p50", "eps_w": 0.01, "controllers": "single"},
    "report": False,
}


def _cmd(*args: object) -> list[str]:
    return [sys.executable, "-m", "qsls.cli.main", *map(str, args)]


def _qsls(*args: object, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(_cmd(*args), cwd=cwd, capture_output=True, text=True)


def _config(tmp_path: Path, **changes) -> Path:
    data = {**SMALL, **changes}
    cfg = tmp_path / f"{data['name']}.yaml"
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    return cfg


def _ran(proc: subprocess.CompletedProcess) -> set[str]:
    assert proc.returncode == 0, proc.stderr[-3000:]
    return {k for k, v in _statuses(proc.stderr).items() if v == "ran"}


def _alive(pid: int) -> bool:
    """Running (a zombie waiting for its reaper is dead)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    state = next(ln for ln in status.splitlines() if ln.startswith("State:"))
    return "Z" not in state.split()[1]


def _children(pid: int) -> list[int]:
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True)
    return [int(p) for p in out.stdout.split()]


def _workers(pid: int, n: int = 2, timeout: float = 60) -> list[int]:
    """The ``n`` worker processes of ``pid``, once they are all running."""
    deadline = time.monotonic() + timeout
    while len(found := _children(pid)) < n and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(found) == n, found
    return found


def interruptible(cmd: list, **kw: object) -> subprocess.Popen:
    """``subprocess.Popen(cmd, **kw)`` whose process answers Ctrl-C even when this one
    ignores SIGINT, as a shell's background job (``pytest &``) does: an ignored signal stays
    ignored across ``exec``, a handled one is reset to its default there."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return subprocess.Popen(cmd, **kw)  # type: ignore[call-overload]
    finally:
        signal.signal(signal.SIGINT, previous)


def _wait_for(pattern: str, proc: subprocess.Popen, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while not glob.glob(pattern):
        assert proc.poll() is None, "the run ended before the moment awaited"
        assert time.monotonic() < deadline, f"no {pattern} after {timeout} s"
        time.sleep(0.05)


# --------------------------------------------------------------------------- item 3
@pytest.mark.slow
def test_a_missing_or_changed_output_reruns_its_stage_and_everything_after(tmp_path):
    cfg = _config(tmp_path)
    run = tmp_path / "runs" / "small"
    assert _ran(_qsls("run", cfg, cwd=tmp_path)) == {
        "simulate/train_1", "ingest/train_1", "simulate/train_2", "ingest/train_2", "fit",
        "synth",
    }  # fmt: skip
    model = (run / "fit" / "error_model.yaml").read_bytes()

    (run / "fit" / "error_model.yaml").unlink()
    proc = _qsls("run", cfg, cwd=tmp_path)
    assert _ran(proc) == {"fit", "synth"}
    assert "error_model.yaml is missing" in proc.stderr
    assert (run / "fit" / "error_model.yaml").read_bytes() == model

    with open(run / "ingest" / "train_1" / "flight.parquet", "ab") as fh:
        fh.write(b"edited")
    proc = _qsls("run", cfg, cwd=tmp_path)
    assert _ran(proc) == {"ingest/train_1", "fit", "synth"}
    assert "flight.parquet changed" in proc.stderr

    # same bytes, new mtime: hashed, found unchanged, skipped
    os.utime(run / "ingest" / "train_2" / "flight.parquet")
    assert _ran(_qsls("run", cfg, cwd=tmp_path)) == set()

    # --from report: no stage reruns, the report is written
    cfg_report = _config(tmp_path, report=True)
    proc = _qsls("run", cfg_report, "--from", "report", cwd=tmp_path)
    assert _ran(proc) == set()
    assert (tmp_path / "runs" / "small" / "report" / "index.html").is_file()


# --------------------------------------------------------------------------- item 4
@pytest.mark.slow
def test_a_second_run_of_one_folder_is_refused_and_a_killed_runs_lock_taken_over(tmp_path):
    cfg = _config(tmp_path, simulate={**SMALL["simulate"], "duration": 20})  # a longer first run
    run = tmp_path / "runs" / "small"
    first = subprocess.Popen(
        _cmd("run", cfg), cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        _wait_for(str(run / "simulate" / "*"), first)
        second = _qsls("run", cfg, cwd=tmp_path)
        assert second.returncode == 2, second.stderr
        assert f"another qsls process (pid {first.pid}) is writing this run folder" in (
            second.stderr
        )
        assert "Traceback" not in second.stderr
        _, err = first.communicate(timeout=300)
        assert first.returncode == 0, err[-2000:]
    finally:
        if first.poll() is None:
            first.kill()
    assert _ran(_qsls("run", cfg, cwd=tmp_path)) == set()

    # a run killed with SIGKILL leaves its lock file; the next run takes it over
    (run / "fit" / "error_model.yaml").unlink()
    killed = subprocess.Popen(_cmd("run", cfg), cwd=tmp_path, stderr=subprocess.DEVNULL)
    _wait_for(str(run.parent / ".small.lock"), killed)
    killed.send_signal(signal.SIGKILL)
    killed.wait(30)
    assert (run.parent / ".small.lock").is_file()
    assert "fit" in _ran(_qsls("run", cfg, cwd=tmp_path))
    assert not (run.parent / ".small.lock").exists()


def test_a_stage_output_folder_held_by_another_process_is_refused(tmp_path):
    from tests.test_fit import vio_flights

    flights, _ = vio_flights(tmp_path / "flights", n=1)
    out = tmp_path / "fit"
    with FolderLock(out):  # this test process holds it, as another qsls would
        proc = _qsls("fit", *flights, "--out", out, "--no-figures", cwd=tmp_path)
    assert proc.returncode == 2
    assert f"another qsls process (pid {os.getpid()}) is writing this output folder" in (
        proc.stderr
    )
    assert not out.exists()
    proc = _qsls("fit", *flights, "--out", out, "--no-figures", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert not list(tmp_path.glob(".fit.*"))


# --------------------------------------------------------------------------- item 5
FLY = {"seeds": [0, 1, 2, 3], "duration": 12, "conditions": ["regular"], "jobs": 2}
BEFORE_FLY = {"simulate/train_1", "ingest/train_1", "fit", "synth"}


@pytest.fixture(scope="module")
def before_fly(tmp_path_factory) -> Path:
    """The fly config's stages before fly, run once: the ``runs`` folder each signal case
    copies (the stages' keys hold no absolute path, so the copy is up to date)."""
    work = tmp_path_factory.mktemp("before_fly")
    cfg = _config(work, name="fly", flights=SMALL["flights"][:1])
    assert _ran(_qsls("run", cfg, cwd=work)) == BEFORE_FLY
    return work / "runs"


@pytest.mark.slow
@pytest.mark.parametrize(
    "sig", [signal.SIGTERM, signal.SIGKILL, signal.SIGINT], ids=["SIGTERM", "SIGKILL", "SIGINT"]
)
def test_a_signal_during_fly_leaves_no_temporary_and_no_worker(tmp_path, sig, before_fly):
    import os

    shutil.copytree(before_fly, tmp_path / "runs")
    cfg = _config(tmp_path, name="fly", flights=SMALL["flights"][:1], fly=FLY)
    run = tmp_path / "runs" / "fly"
    systmp = tmp_path / "systmp"  # the system temporary folder, as this run sees it
    systmp.mkdir()
    proc = interruptible(
        _cmd("run", cfg), cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, env={**os.environ, "TMPDIR": str(systmp)}, start_new_session=True,
    )  # fmt: skip
    try:
        # inside the flights: a worker is flying one (its simulation's temporary exists),
        # ten more are queued behind the two running (twelve: pd, l1_robust, se3 x 4 seeds)
        _wait_for(str(run / ".fly.tmp-*" / ".scratch" / ".*.tmp-*"), proc)
        workers = _workers(proc.pid, 2, timeout=30)
        t0 = time.monotonic()
        if sig == signal.SIGINT:  # Ctrl-C: the terminal signals the whole process group
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
    # the interrupted run found the copied stages up to date: only fly was started
    assert {k for k, v in _statuses(err).items() if v == "skipped"} == BEFORE_FLY, err
    deadline = time.monotonic() + 10
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(w) for w in workers), "a worker outlived the run"
    # fly's scratch lives in the stage's temporary folder, never in the system's
    assert not list(systmp.glob("qsls-fly-*"))
    if sig == signal.SIGTERM:
        assert proc.returncode == 143
        assert "terminated (SIGTERM); no partial output was kept" in err
        assert not list(run.glob(".*tmp-*")) and not list(run.glob(".*.lock"))
    elif sig == signal.SIGINT:
        assert proc.returncode == 130 and "interrupted; no partial output was kept" in err
        assert not list(run.glob(".*tmp-*")) and not list(run.glob(".*.lock"))
    else:
        assert list(run.glob(".fly.tmp-*"))  # SIGKILL cannot be handled: the next run cleans
    t1 = time.monotonic()
    again = _qsls("run", cfg, cwd=tmp_path)
    again_s = time.monotonic() - t1
    assert _ran(again) == {"fly"}  # the killed stage never counts as done
    if sig == signal.SIGINT:
        # the workers are not awaited: far less than the ten queued flights would take (the
        # rerun flies all twelve, at the same load)
        assert took < min(5, again_s / 4), f"Ctrl-C took {took:.1f} s to end the run"
    # the run ends with the answer: each controller's verdict on the flown flights
    out = again.stdout.strip().splitlines()
    tail = out[out.index("Certified bound on the flown flights:") + 1 :]
    verdict = [ln for ln in tail if re.search(
        r": (holds|FAILS|no certified bound), worst \|\|e\|\|/gamma_nominal [0-9.]+ ", ln)
        or re.search(r": (every assumption holds on|FAILS on [0-9]+ of) [0-9]+ flights?", ln)]  # fmt: skip
    assert {ln.split(":")[0].strip() for ln in verdict} == {"pd", "l1_robust"}
    # each verdict is led by its controller's promise (or what it does not promise)
    assert len(tail) == 2 * len(verdict) and tail[-1] in verdict
    assert not list(run.glob(".*tmp-*")) and not list(run.rglob(".*.lock"))
    assert (run / "fly" / "manifest.json").is_file()
